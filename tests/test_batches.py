"""A batch read together stays stacked on its way to the loop (hbeo.batches): the same tensors the default
collation would build from its items, without indexing and stacking them again every step."""
import pytest
import torch
from torch.utils.data import default_collate

from hbeo.batches import Stacked, collate


def _batch(n=5):
    g = torch.Generator().manual_seed(0)
    return {"depth": torch.rand(n, 1, 6, 8, generator=g), "label": torch.randint(0, 10, (n,), generator=g),
            "rotation": torch.rand(n, 3, 3, generator=g), "coeffs": torch.rand(n, 4, generator=g),
            "object_index": torch.arange(n)}


def test_a_stacked_batch_collates_to_what_its_items_would():
    b = _batch()
    s = Stacked(b)
    items = list(s)
    assert len(s) == len(items) == 5 and set(items[0]) == set(b)
    assert torch.equal(s[-1]["depth"], b["depth"][4]) and s[2]["label"].shape == ()
    ours, theirs = collate(s), default_collate(items)
    assert set(ours) == set(theirs)
    for k in theirs:
        assert ours[k].dtype == theirs[k].dtype and torch.equal(ours[k], theirs[k]), k
    # a plain list of items still goes through torch's default collation
    assert all(torch.equal(collate(items)[k], theirs[k]) for k in theirs)


def test_a_stacked_batch_refuses_what_is_not_one():
    with pytest.raises(TypeError, match="dict of tensors"):
        Stacked({})
    with pytest.raises(TypeError, match="dict of tensors"):
        Stacked({"depth": torch.zeros(2, 1), "name": "chair"})
    with pytest.raises(ValueError, match=r"different lengths \[2, 3\]"):
        Stacked({"depth": torch.zeros(2, 1), "label": torch.zeros(3)})
    with pytest.raises(IndexError, match="item 5 of a batch of 5"):
        Stacked(_batch())[5]

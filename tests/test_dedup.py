"""Near-duplicate groups and the grouped validation split (hbeo.data.dedup), the split rule the
profiles select (datasets.validation_mask) and class-mean accuracy, on tiny hand-made grids."""
import numpy as np
import pytest
import torch

from hbeo.data import dedup
from hbeo.data.datasets import split_objects, validation_mask
from hbeo.evaluation.evaluate import class_mean_accuracy
from hbeo.model.loop import ValidationMeans


def _box(lo, hi, n=6):
    g = np.zeros((n, n, n), bool)
    g[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    return g


def test_pairwise_iou_by_hand():
    a, b = _box((0, 0, 0), (2, 2, 2)), _box((1, 0, 0), (3, 2, 2))      # 8 voxels each, 4 shared
    iou = dedup.pairwise_iou(np.stack([a, b, np.zeros_like(a)]))
    assert iou[0, 1] == pytest.approx(4 / 12) and iou[0, 0] == 1 and iou[2, 2] == 0
    with pytest.raises(ValueError, match="shape"):
        dedup.pairwise_iou(np.zeros((2, 3, 3)))


def test_nearest_iou_excludes_self_and_other_classes():
    a, a2, b = _box((0, 0, 0), (2, 2, 2)), _box((0, 0, 0), (2, 2, 3)), _box((3, 3, 3), (5, 5, 5))
    grids, labels = np.stack([a, a2, a, b]), np.array([0, 0, 1, 1])
    best, where = dedup.nearest_iou(grids, labels)
    assert best[0] == pytest.approx(8 / 12) and where[0] == 1
    assert best[2] == 0 and where[2] == 3             # its identical twin is in another class
    best, where = dedup.nearest_iou(grids[:1], labels[:1], grids[1:], labels[1:])
    assert best[0] == pytest.approx(8 / 12) and where[0] == 0


def _twins(n_groups=12, sizes=(1, 2, 3), classes=2, seed=0):
    """Grids in groups of identical grids (distinct groups overlap nowhere), several classes."""
    rng = np.random.default_rng(seed)
    grids, labels, truth = [], [], []
    g = 0
    for c in range(classes):
        for k in range(n_groups):
            size = sizes[k % len(sizes)]
            cell = np.zeros((8, 8, 8), bool)
            cell.flat[4 * g:4 * g + 4] = True          # groups never overlap (at most 128 groups)
            for _ in range(size):
                grids.append(cell)
                labels.append(c)
                truth.append(g)
            g += 1
    order = rng.permutation(len(labels))
    return np.stack(grids)[order], np.array(labels)[order], np.array(truth)[order]


def test_twin_groups_are_the_connected_components():
    grids, labels, truth = _twins()
    groups = dedup.twin_groups(grids, labels, 0.95)
    # same partition as the truth
    assert len(np.unique(groups)) == len(np.unique(truth))
    for g in np.unique(groups):
        assert len(np.unique(truth[groups == g])) == 1
    # a chain a~b~c with a !~ c is one group
    a, b, c = _box((0, 0, 0), (4, 2, 2)), _box((1, 0, 0), (5, 2, 2)), _box((2, 0, 0), (6, 2, 2))
    assert dedup.pairwise_iou(np.stack([a, c]))[0, 1] < 0.5
    assert len(np.unique(dedup.twin_groups(np.stack([a, b, c]), [0, 0, 0], 0.6))) == 1
    with pytest.raises(ValueError, match="threshold"):
        dedup.twin_groups(grids, labels, 0)


def test_grouped_split_keeps_groups_whole_stratified_deterministic():
    grids, labels, truth = _twins(n_groups=30)
    groups = dedup.twin_groups(grids, labels, 0.95)
    val = dedup.split_groups(labels, groups, 0.2, seed=3)
    for g in np.unique(groups):
        assert len(np.unique(val[groups == g])) == 1            # never split
    for c in np.unique(labels):
        n = (labels == c).sum()
        assert 0 < val[labels == c].sum() <= round(0.2 * n)
        assert val[labels == c].sum() >= round(0.2 * n) - 2     # about val_fraction (groups of <= 3)
    assert np.array_equal(val, dedup.split_groups(labels, groups, 0.2, seed=3))
    assert not np.array_equal(val, dedup.split_groups(labels, groups, 0.2, seed=4))
    assert not dedup.split_groups(labels, groups, 0.0).any()
    # singletons only: the same counts as the object split
    single = np.arange(len(labels))
    assert dedup.split_groups(labels, single, 0.2, 0).sum() == split_objects(labels, 0.2, 0).sum()


def test_grouped_split_one_big_group_gives_its_smallest_group():
    labels = np.zeros(10, int)
    groups = np.array([0] * 9 + [1])
    val = dedup.split_groups(labels, groups, 0.1, 0)
    assert val.tolist() == [False] * 9 + [True]
    assert not dedup.split_groups(labels, np.zeros(10, int), 0.3, 0).any()   # one group: nothing to hold out


def test_validation_mask_rules():
    grids, labels, _ = _twins()
    assert np.array_equal(validation_mask(labels, 0.2, 0, "object"), split_objects(labels, 0.2, 0))
    g = validation_mask(labels, 0.2, 0, "grouped", grids, 0.95)
    assert np.array_equal(g, dedup.split_groups(labels, dedup.twin_groups(grids, labels, 0.95), 0.2, 0))
    with pytest.raises(ValueError, match="grouped.*grid"):
        validation_mask(labels, 0.2, 0, "grouped")
    with pytest.raises(ValueError, match="unknown val_split 'twins'"):
        validation_mask(labels, 0.2, 0, "twins")


def test_class_mean_accuracy_by_hand():
    true = ["a", "a", "a", "a", "b", "c", "c"]
    pred = ["a", "a", "a", "b", "b", "a", "c"]       # a 3/4, b 1/1, c 1/2
    assert class_mean_accuracy(true, pred) == pytest.approx((0.75 + 1 + 0.5) / 3)
    assert np.isnan(class_mean_accuracy([], []))
    with pytest.raises(ValueError, match="same"):
        class_mean_accuracy(["a"], ["a", "b"])
    # the training loop's validation means agree, batch by batch
    means = ValidationMeans()
    codes = {"a": 0, "b": 1, "c": 2}
    t, p = torch.tensor([codes[x] for x in true]), torch.tensor([codes[x] for x in pred])
    for s in (slice(0, 3), slice(3, 7)):
        means.add(torch.tensor(1.0), {}, torch.nn.functional.one_hot(p[s], 3).float(), t[s])
    m = means.means()
    assert m["class_mean_accuracy"] == pytest.approx((0.75 + 1 + 0.5) / 3)
    assert m["accuracy"] == pytest.approx(5 / 7)


def test_training_data_holds_out_the_grouped_validation_records(ci_run, ci_grids, ci_render):
    """training_data's grouped split (memory source) holds out exactly validation_records' objects under
    a grouped profile, and never splits a group; a mesh dataset without grids is refused by name."""
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.model.trainingdata import ViewOptions, training_data
    prof = config.get_profile("ci", val_split="grouped", twin_iou=0.6)
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    data = training_data(ci_run, ViewOptions(), progress=False, val_split="grouped", twin_iou=0.6)
    m = data.manifest
    held = {m.object_ids[p] for p in np.unique(m.image_objects()[data.val.indices])}
    val = datasets.validation_records(ds, prof, gridset=ci_grids["train"])
    assert held == {r.id for r in val} and len(held) >= len(ds.classes)
    train = datasets.select(ds, "train", prof)
    groups = dedup.twin_groups(datasets.record_grids(train, ci_grids["train"]),
                               [ds.classes.index(r.cls) for r in train], 0.6)
    for g in np.unique(groups):
        assert len({r.id in held for r, k in zip(train, groups) if k == g}) == 1
    with pytest.raises(ValueError, match="has no grid.*GridSet"):
        datasets.validation_records(ds, prof)

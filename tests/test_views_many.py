"""Many objects' views ray-marched together (ObjectViews.views_many / query_views_many, what a GPU does: one
march instead of one per object) give the arrays of rendering them one object at a time, and an evaluation
chunk with a bad object still scores the others and names it."""
import numpy as np
import pytest

from hbeo import config
from hbeo.data import datasets
from hbeo.render.views import ObjectViews, RenderSettings


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    from test_streaming import _tiny_vox30
    path = _tiny_vox30(tmp_path_factory.mktemp("many") / "tiny.npz")
    ds = datasets.get_dataset("modelnet10-vox30", path=path)
    return ds, RenderSettings.from_profile(config.get_profile("ci"), backend="torch")


def _same(a: list[dict], b: list[dict]):
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert set(x) == set(y)
        for k in x:
            assert np.array_equal(np.asarray(x[k]), np.asarray(y[k])), k


@pytest.mark.parametrize("noise", [False, True])
def test_views_marched_together_are_the_views_rendered_one_object_at_a_time(grids, noise, monkeypatch):
    from dataclasses import replace
    ds, rs = grids
    rs = replace(rs, noise=noise, views_per_object=3)
    recs = ds.records(split="train")[:7]
    ov = ObjectViews(rs)
    assert not ov.batched()                                     # no GPU here: object by object by default
    one = ov.views_many(recs, list(range(7)), [0] * 7, "train", epoch=2)
    _same(ov.views_many(recs, list(range(7)), [0] * 7, "train", epoch=2, batched=True), one)
    q = ov.query_views_many(recs, "test", 3, labels=[1] * 7)
    _same(ov.query_views_many(recs, "test", 3, labels=[1] * 7, batched=True), q)
    _same(q, [ov.query_views(r, "test", 3, 1) for r in recs])
    monkeypatch.setattr(ObjectViews, "MANY_RAYS", 2 * rs.intrinsics.width * rs.intrinsics.height)   # 2 views a march
    _same(ov.query_views_many(recs, "test", 3, labels=[1] * 7, batched=True), q)


def test_an_evaluation_chunk_marched_together_still_names_a_bad_object_and_scores_the_rest(grids, monkeypatch):
    """With the chunk's objects marched together (forced here, as on a GPU), an object that cannot be
    rendered sends the chunk back to one object at a time: the bad object is named in the failures, the
    others are rendered as before."""
    from hbeo.evaluation.evaluate import rendered_chunks
    from hbeo.render import views
    ds, rs = grids
    recs = ds.records(split="test")
    bad = recs[2]
    real = views.check_grid_records

    def check(records):                      # the bad object's grid cannot be marched, alone or with others
        if any(r is bad for r in records):
            raise ValueError(f"object {bad.id} is broken")
        real(records)
    monkeypatch.setattr(views, "check_grid_records", check)
    monkeypatch.setattr(ObjectViews, "batched", lambda self: True)
    class Bar:
        n = 0

        def update(self, k):
            self.n += k
    failures, bar = [], Bar()
    batches = list(rendered_chunks(rs, recs, "test", len(recs), failures, bar))
    assert [r.id for _, r, _, _ in batches[0]] == [r.id for r in recs if r is not bad]
    assert len(failures) == 1 and bad.id in str(failures[0]) and bar.n == 1

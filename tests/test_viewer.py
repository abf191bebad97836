"""The notebooks' rotatable 3-D views (hbeo.lessons.viewer): voxel faces, depth points in the object frame,
the plotly figure, its offline HTML and the static figure beside it."""
import re
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from hbeo import conventions as C
from hbeo.report import book
from hbeo.lessons import viewer
from hbeo.model.modelfile import ModelSettings
from hbeo.rotations import yaw_elevation_to_matrix
from hbeo.rundir import RunDir


def _chair_like():
    g = np.zeros((30, 30, 30), bool)
    g[6:22, 8:22, 3:11] = True          # seat block
    g[6:22, 19:22, 11:26] = True        # back
    return g


def _normals(v, f):
    tri = v[f]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.mean(1)


def test_voxel_faces_of_one_voxel_form_a_closed_cube_facing_out():
    g = np.zeros((30, 30, 30), bool)
    g[3, 4, 5] = True
    v, f = viewer.voxel_faces(g)
    assert v.shape == (8, 3) and f.shape == (12, 3)
    assert v.min(0).tolist() == [3, 4, 5] and v.max(0).tolist() == [4, 5, 6], "corners in grid coordinates"
    n, centre = _normals(v, f)
    assert np.all(np.sum(n * (centre - [3.5, 4.5, 5.5]), axis=1) > 0), "normals point out of the voxel"


def test_voxel_faces_drop_shared_faces_and_close_a_box():
    g = np.zeros((30, 30, 30), bool)
    g[3:5, 4, 5] = True                 # two voxels side by side: 10 exposed faces
    v, f = viewer.voxel_faces(g)
    assert f.shape == (20, 3) and v.shape == (12, 3)
    box = np.zeros((30, 30, 30), bool)
    box[0:4, 2:7, 27:30] = True         # touching the border: its outer faces are exposed too
    v, f = viewer.voxel_faces(box)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2), "every edge of a solid box's surface belongs to two triangles"
    assert len(f) == 2 * 2 * (4 * 5 + 4 * 3 + 5 * 3)
    assert viewer.voxel_faces(np.zeros((30, 30, 30), bool))[1].shape == (0, 3)


def test_surface_voxels_of_a_solid_cube():
    g = np.zeros((30, 30, 30), bool)
    g[10:15, 10:15, 10:15] = True
    assert len(viewer.surface_voxels(g)) == 5 ** 3 - 3 ** 3


def test_depth_points_land_on_the_rendered_grid():
    """A grid's surface rendered at a pose and moved back with that pose lies in the grid's occupied voxels;
    moved with another pose, it does not."""
    from hbeo.render.renderer import Renderer, grid_mesh
    grid = _chair_like()
    K = C.Intrinsics.kinect(160, 120)
    R = yaw_elevation_to_matrix(np.radians(30.0), np.radians(25.0))
    t = np.array([0.05, -0.02, 1.6])
    with Renderer(K, backend="embree") as r:
        depth = r.render(grid_mesh(grid, 1.0, smooth=0), R, t)
    u = viewer.depth_points(depth, K, R, t, 1.0)
    assert len(u) > 500 and u.shape[1] == 3
    edt = ndimage.distance_transform_edt(~grid)
    i = np.clip(np.floor(u).astype(int), 0, 29)
    assert np.quantile(edt[i[:, 0], i[:, 1], i[:, 2]], 0.99) <= 1.0
    wrong = viewer.depth_points(depth, K, yaw_elevation_to_matrix(np.radians(120.0), np.radians(25.0)), t, 1.0)
    j = np.clip(np.floor(wrong).astype(int), 0, 29)
    assert np.mean(edt[j[:, 0], j[:, 1], j[:, 2]] > 1.0) > 0.2


def _view(truth=True, other=True, n=5000):
    pts = np.random.default_rng(0).uniform(5, 25, (n, 3))
    g = _chair_like()
    return viewer.View3D(g, pts, "true pose", truth=g if truth else None, other_points=pts + 1 if other else None,
                         other_pose="HBEO's predicted pose" if other else None, title="a test view")


def test_figure_has_the_completion_the_truth_beside_it_and_the_points():
    fig = viewer.figure(_view())
    types = [t.type for t in fig.data]
    assert types == ["mesh3d", "mesh3d"] + ["scatter3d"] * 4
    comp, truth = fig.data[0], fig.data[1]
    assert np.min(truth.x) - np.min(comp.x) == pytest.approx(viewer.TRUTH_OFFSET)
    pts = fig.data[2:]
    assert all(len(t.x) <= viewer.MAX_POINTS for t in pts)
    assert [t.visible for t in pts] == [True, True, "legendonly", "legendonly"], "the other pose starts hidden"
    assert [t.showlegend for t in pts] == [True, False, True, False], "one legend entry per pose"
    assert fig.layout.scene.aspectmode == "data" and fig.layout.title.text == "a test view"
    alone = viewer.figure(_view(truth=False, other=False))
    assert [t.type for t in alone.data] == ["mesh3d", "scatter3d"]


def test_html_works_offline_and_the_book_accepts_it():
    html = viewer.to_html(viewer.figure(_view()))
    assert html.count("plotly.js v") == 1, "plotly.js embedded once"
    assert not re.search(r"<script[^>]*\bsrc\s*=", html), "no script loaded from anywhere"
    assert book.remote_references(html) == []
    assert "requirejs.config" not in html and "cdn.plot.ly/plotly" not in html
    assert len(html) < 6_000_000
    bare = viewer.to_html(viewer.figure(_view()), include_plotlyjs=False)
    assert "plotly.js v" not in bare and len(bare) < 400_000 and "Plotly.newPlot" in bare
    with pytest.raises(ValueError, match="never a CDN"):
        viewer.to_html(viewer.figure(_view()), include_plotlyjs="cdn")


def test_static_figure_and_show_save_the_png(tmp_path, capsys):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig = viewer.static_figure(_view())
    assert len(fig.axes) == 3 and fig.axes[2].name == "3d"
    plt.close(fig)
    fig = viewer.static_figure(_view(truth=False))
    assert len(fig.axes) == 2
    plt.close(fig)
    run = RunDir.of(tmp_path)
    fig = viewer.show(_view(), run, "06_view3d")
    plt.close(fig)
    assert run.figure("06_view3d").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_frame_view_moves_the_points_with_the_predicted_pose():
    K = C.Intrinsics.kinect(40, 30)
    depth = np.zeros((30, 40), np.float32)
    depth[10:20, 15:25] = 1.5
    R = yaw_elevation_to_matrix(np.radians(40.0), np.radians(20.0))
    t = np.array([0.0, 0.0, 1.5])
    frame = SimpleNamespace(object_depth=depth, intrinsics=K, depth_path=None,
                            truth={"rotation": np.eye(3), "translation": t})
    answer = SimpleNamespace(rotation=R[None], translation=t[None], scale=np.ones(1), grids=_chair_like()[None],
                             class_names=["chair"], probabilities=np.array([[0.7, 0.3]]))
    model = SimpleNamespace(settings=ModelSettings(object_size=1.0))
    v = viewer.frame_view(model, frame, answer)
    assert v.truth is None and v.pose == "HBEO's predicted pose" and v.other_pose == "true pose"
    np.testing.assert_allclose(v.points, viewer.depth_points(depth, K, R, t, 1.0))
    one = np.zeros((30, 40), np.float32)
    one[15, 20] = 1.5                   # on the optical axis, at the object's centre: the grid's centre
    centre = viewer.depth_points(one, C.Intrinsics(40, 40, 20, 15, 40, 30), np.eye(3), t, 1.0)
    np.testing.assert_allclose(centre, [[15.0, 15.0, 15.0]])
    assert "chair" in v.title and "predicted pose" in v.title

import numpy as np
import pytest

from hbeo.errors import DataError
from hbeo.data.meshio import parse_off, read_mesh

SQUARE = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n"


def test_standard_header_and_ngon_fan_triangulation():
    v, f = parse_off("OFF\n# comment\n4 1 0\n" + SQUARE + "4 0 1 2 3\n")
    assert v.shape == (4, 3)
    assert f.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_modelnet_broken_one_line_header():
    v, f = parse_off("OFF4 2 0\n" + SQUARE + "3 0 1 2\n3 0 2 3\n")
    assert v.shape == (4, 3) and f.shape == (2, 3)


def test_mixed_polygons_with_face_colours_and_pentagon():
    text = "OFF\n5 2 0\n" + SQUARE + "0.5 1.5 0\n3 0 1 2 255 0 0\n5 0 1 4 2 3\n"
    v, f = parse_off(text)
    assert f.tolist() == [[0, 1, 2], [0, 1, 4], [0, 4, 2], [0, 2, 3]]


@pytest.mark.parametrize("text, msg", [
    ("PLY\n", "not an OFF file"),
    ("OFF\n4 2\n" + SQUARE + "3 0 1 2\n", "truncated OFF"),
    ("OFF\n4 1 0\n" + SQUARE + "3 0 1 9\n", "refers to vertex 9"),
    ("OFF\n4 1 0\n0 0 0\n1 x 0\n1 1 0\n0 1 0\n3 0 1 2\n", "unreadable vertex"),
    ("OFF\n4 1 0\n" + SQUARE + "2 0 1\n", "unreadable face line"),
    ("OFF\nfour 1 0\n", "bad OFF counts"),
    ("OFF\n4 1 0\n0 0 nan\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n", "NaN"),
])
def test_bad_off_names_file_and_problem(text, msg, tmp_path):
    p = tmp_path / "bad.off"
    p.write_text(text)
    with pytest.raises(DataError, match=msg) as err:
        read_mesh(p)
    assert "bad.off" in str(err.value)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(DataError, match="nothere.off: no such mesh file"):
        read_mesh(tmp_path / "nothere.off")
    (tmp_path / "x.fbx").write_text("x")
    with pytest.raises(DataError, match="unsupported mesh format"):
        read_mesh(tmp_path / "x.fbx")


def test_mesh_without_faces(tmp_path):
    p = tmp_path / "empty.off"
    p.write_text("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(DataError, match="no faces"):
        read_mesh(p)


def test_real_modelnet_meshes_keep_unused_vertices(sample_dir):
    m = read_mesh(sample_dir / "bathtub" / "train" / "bathtub_0001.off")
    assert m.vertices.shape == (3514, 3) and m.faces.shape == (3546, 3)
    assert len(np.unique(m.faces)) < len(m.vertices)      # the file has unused vertices; kept


def test_obj_ply_stl_via_trimesh(tmp_path):
    import trimesh
    box = trimesh.creation.box((1, 2, 3))
    for ext in ("obj", "ply", "stl"):
        p = tmp_path / f"box.{ext}"
        box.export(p)
        m = read_mesh(p)
        assert np.allclose(m.extents, (1, 2, 3))


def _trimesh_off(text):
    import io

    import trimesh
    return trimesh.load(io.BytesIO(text.encode()), file_type="off", process=False, force="mesh")


def test_why_off_keeps_its_own_parser():
    """trimesh's OFF loader reads ModelNet's one-line header, but misreads other valid or broken
    OFF files (see hbeo.data.meshio). If this test starts failing, trimesh got better: re-check
    whether parse_off can go."""
    # ModelNet's broken header "OFF4 2 0": trimesh is right, so this is NOT why parse_off stays
    text = "OFF4 2 0\n" + SQUARE + "3 0 1 2\n3 0 2 3\n"
    v, f = parse_off(text)
    m = _trimesh_off(text)
    assert np.array_equal(m.vertices, v) and np.array_equal(m.faces, f)

    # a comment after the counts line: trimesh silently returns wrong vertices and drops the face
    text = "OFF\n4 1 0\n0 0 0\n# made by hand\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n"
    v, f = parse_off(text)
    assert v.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]] and f.tolist() == [[0, 1, 2]]
    m = _trimesh_off(text)
    assert m.vertices.tolist() != v.tolist() and len(m.faces) == 0

    # a truncated file (the header promises 2 faces, there is 1): trimesh silently loses the face
    text = "OFF\n4 2 0\n" + SQUARE + "3 0 1 2\n"
    assert len(_trimesh_off(text).faces) == 1
    with pytest.raises(DataError, match="truncated OFF"):
        parse_off(text, "cut.off")

    # a NaN coordinate: trimesh accepts it
    text = "OFF\n4 1 0\n0 0 nan\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n"
    assert np.isnan(_trimesh_off(text).vertices).any()
    with pytest.raises(DataError, match="NaN"):
        parse_off(text)

    # a pentagon next to a triangle with a face colour: trimesh fails, parse_off fans it
    text = "OFF\n5 2 0\n" + SQUARE + "0.5 1.5 0\n3 0 1 2 255 0 0\n5 0 1 4 2 3\n"
    with pytest.raises(Exception):
        _trimesh_off(text)
    assert parse_off(text)[1].tolist() == [[0, 1, 2], [0, 1, 4], [0, 4, 2], [0, 2, 3]]

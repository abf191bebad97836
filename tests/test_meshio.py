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


@pytest.mark.parametrize("text, extra", [
    ("OFF\n4 1 0\n" + SQUARE + "3 0 1 2\n3 0 2 3\n", "'3 0 2 3'"),             # a face more
    ("OFF\n3 1 0\n" + SQUARE + "3 0 1 2\n", "'3 0 1 2'"),                      # a vertex more
    ("OFF\n4 1 0\n" + SQUARE + "3 0 1 2\n# end\n3 0 2 3\n", "'3 0 2 3'"),      # slow path (comments)
])
def test_data_beyond_the_header_counts_is_refused_not_dropped(text, extra, tmp_path):
    p = tmp_path / "long.off"
    p.write_text(text)
    with pytest.raises(DataError, match=r"long\.off: OFF header promises .* extra \(first: " + extra) as err:
        read_mesh(p)
    assert "fix the counts line" in str(err.value)
    # trailing blank lines and comments are no data
    assert parse_off("OFF\n4 1 0\n" + SQUARE + "3 0 1 2\n\n# made by hand\n\n")[1].shape == (1, 3)


def test_real_modelnet_meshes_have_no_data_beyond_their_counts(sample_dir):
    for p in sorted(sample_dir.glob("*/*/*.off")):
        assert read_mesh(p).faces.shape[0] > 0


def test_utf8_byte_order_mark_is_accepted(tmp_path):
    p = tmp_path / "bom.off"
    p.write_bytes("\ufeffOFF\n4 2 0\n".encode() + (SQUARE + "3 0 1 2\n3 0 2 3\n").encode())
    m = read_mesh(p)
    assert m.vertices.shape == (4, 3) and m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert parse_off("\ufeffOFF4 1 0\n" + SQUARE + "3 0 1 2\n")[1].shape == (1, 3)


@pytest.mark.parametrize("far", [[1e11, 0, 0], [0, 0, 1e11], [1e11, 1e11, 1e11]])
def test_one_far_vertex_is_a_too_wide_range_not_collinear(far, tmp_path):
    from hbeo.data.meshio import check_mesh
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], far], float)
    for faces in ([[0, 1, 2], [0, 1, 3]], [[0, 1, 2]]):            # the far vertex used by a face, or not
        with pytest.raises(DataError, match=r"^far\.off: degenerate mesh: its coordinates span too wide a "
                                            r"range: .*vertex 3 at \(" + ", ".join(f"{x:g}" for x in far)
                                            .replace("+", r"\+") + r"\)") as err:
            check_mesh(v, np.array(faces), "far.off")
        assert "collinear" not in str(err.value)
    # truly collinear vertices (even far from the origin) still say so
    line = np.arange(50)[:, None] * np.array([[0.1, 0.2, 0.3]]) + 1e6
    with pytest.raises(DataError, match="all 50 vertices are collinear"):
        check_mesh(line, np.array([[0, 1, 2]]), "line.off")

# PYTHONPATH=python /usr/bin/python3 -m pytest tests/python/test_io.py
"""Mesh file I/O from Python: round trips, face conversion and its validation, input layouts,
error types, and the public test meshes in ../shared/data/meshes when they are present."""
import os
import pathlib

import numpy as np
import pytest

from larap.io import faces_to_csr, load_mesh, save_mesh

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SHARED_MESHES = os.path.join(REPO, "..", "shared", "data", "meshes")


def cube():
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                  [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], np.float64)
    F = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4],
                  [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]], np.int64)
    return V, F


def random_mesh(seed=0, n=50, m=80):
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-5, 5, size=(n, 1))
    F = rng.integers(0, n, size=(m, 3))
    return V, F


# ---------------------------------------------------------------- round trips

@pytest.mark.parametrize("name,ascii", [("m.obj", False), ("m.off", False), ("m.ply", False),
                                        ("m.ply", True), ("M.OBJ", False)])
def test_round_trip_is_exact(tmp_path, name, ascii):
    V, F = random_mesh()
    save_mesh(tmp_path / name, V, F, ascii=ascii)
    V2, F2 = load_mesh(tmp_path / name)
    assert V2.dtype == np.float64 and V2.shape == V.shape
    assert np.array_equal(V2, V)  # bit-exact: OBJ/OFF/ascii PLY write shortest round-trip digits
    assert F2.dtype == np.int64 and np.array_equal(F2, F)
    assert not os.path.exists(str(tmp_path / name) + ".tmp")


def test_mixed_polygons_come_back_as_a_list(tmp_path):
    V, _ = cube()
    faces = [[0, 1, 2], np.array([0, 2, 3, 4], np.int32), (4, 5, 6, 7, 0)]
    for name in ("p.obj", "p.ply", "p.off"):
        save_mesh(tmp_path / name, V, faces)
        _, F = load_mesh(str(tmp_path / name))
        assert isinstance(F, list) and len(F) == 3
        for a, b in zip(F, faces):
            assert a.dtype == np.int64 and np.array_equal(a, np.asarray(b))


def test_a_null_byte_in_a_path_is_refused(tmp_path):
    """The engine reads paths as C strings: "x\0.obj" would have written "x"."""
    keep = tmp_path / "important"
    keep.write_text("the artist's file")
    for path in (str(keep) + "\0.obj", os.fsencode(str(keep) + "\0.obj")):
        with pytest.raises(ValueError, match="null byte"):
            save_mesh(path, np.zeros((3, 3)), [[0, 1, 2]])
        with pytest.raises(ValueError, match="null byte"):
            load_mesh(path)
    assert keep.read_text() == "the artist's file"


def test_point_cloud(tmp_path):
    V = np.arange(12.0).reshape(4, 3)
    for name in ("c.obj", "c.ply", "c.off"):
        save_mesh(tmp_path / name, V, None)
        V2, F2 = load_mesh(tmp_path / name)
        assert np.array_equal(V2, V)
        assert F2.shape == (0, 3) and F2.dtype == np.int64
        save_mesh(tmp_path / name, V, np.zeros((0, 3), np.int64))
        assert load_mesh(tmp_path / name)[1].shape == (0, 3)


def test_loaded_arrays_are_writable_and_independent(tmp_path):
    V, F = cube()
    save_mesh(tmp_path / "c.ply", V, F)
    V2, F2 = load_mesh(tmp_path / "c.ply")
    V2 += 1.0
    F2[0, 0] = 7
    V3, F3 = load_mesh(tmp_path / "c.ply")
    assert np.array_equal(V3, V) and np.array_equal(F3, F)


def test_template_keeps_uvs_and_normals(tmp_path):
    tpl = tmp_path / "t.obj"
    tpl.write_text("mtllib a.mtl\nv 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
                   "usemtl a\nf 1/1/1 2/1/1 3/1/1\n")
    V, F = load_mesh(tpl)
    save_mesh(tmp_path / "o.obj", V * 2 + 0.5, F, template=tpl)
    text = (tmp_path / "o.obj").read_text()
    assert text == ("mtllib a.mtl\nv 0.5 0.5 0.5 1 0 0\nv 2.5 0.5 0.5\nv 0.5 2.5 0.5\nvt 0 0\n"
                    "vn 0 0 1\nusemtl a\nf 1/1/1 2/1/1 3/1/1\n")
    # A template with another vertex count gives a plain OBJ.
    V4 = np.vstack([V, [[5.0, 5.0, 5.0]]])
    save_mesh(tmp_path / "o.obj", V4, F, template=str(tpl))
    assert "vt" not in (tmp_path / "o.obj").read_text()
    assert np.array_equal(load_mesh(tmp_path / "o.obj")[0], V4)


# ---------------------------------------------------------------- input layouts

def test_read_only_non_contiguous_and_other_dtypes(tmp_path):
    V, F = random_mesh(1)
    big = np.zeros((V.shape[0], 6), np.float32)
    big[:, ::2] = V
    Vview = big[:, ::2]                      # float32, strided
    Fwide = np.zeros((F.shape[0], 3, 2), np.int32)
    Fwide[:, :, 0] = F
    Fview = Fwide[:, :, 0]                   # int32, strided
    Vview.flags.writeable = False
    Fview.flags.writeable = False
    save_mesh(tmp_path / "a.ply", Vview, Fview)
    V2, F2 = load_mesh(tmp_path / "a.ply")
    assert np.array_equal(V2, Vview.astype(np.float64)) and np.array_equal(F2, F)
    Vt = np.asfortranarray(V)
    save_mesh(tmp_path / "b.obj", Vt, F.astype(np.uint16))
    assert np.array_equal(load_mesh(tmp_path / "b.obj")[0], V)
    save_mesh(tmp_path / "c.off", V.astype(int), F.tolist())   # integer positions, nested lists
    assert np.array_equal(load_mesh(tmp_path / "c.off")[0], V.astype(int))


def test_save_rejects_bad_shapes_and_values(tmp_path):
    V, F = cube()
    with pytest.raises(ValueError, match=r"\(8, 2\)"):
        save_mesh(tmp_path / "x.obj", V[:, :2], F)
    with pytest.raises(ValueError, match=r"\(24,\)"):
        save_mesh(tmp_path / "x.obj", V.ravel(), F)
    with pytest.raises(TypeError):
        save_mesh(tmp_path / "x.obj", V.astype(complex), F)
    with pytest.raises(ValueError, match="out of range"):
        save_mesh(tmp_path / "x.obj", V, F + 1)
    Vn = V.copy()
    Vn[3, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        save_mesh(tmp_path / "x.obj", Vn, F)
    with pytest.raises(ValueError, match="format"):
        save_mesh(tmp_path / "x.stl", V, F)
    assert not list(tmp_path.iterdir())  # nothing written, no .tmp left


def test_failed_save_keeps_existing_file(tmp_path):
    V, F = cube()
    save_mesh(tmp_path / "k.obj", V, F)
    before = (tmp_path / "k.obj").read_bytes()
    with pytest.raises(ValueError):
        save_mesh(tmp_path / "k.obj", V, F + 10)
    with pytest.raises(OSError):
        save_mesh(tmp_path / "missing-dir" / "k.obj", V, F)
    assert (tmp_path / "k.obj").read_bytes() == before


def test_native_save_checks_shapes(tmp_path):
    from larap import _core
    V, F = cube()
    off, idx = faces_to_csr(F)
    with pytest.raises(ValueError, match=r"\(8, 4\)"):
        _core.save_mesh(str(tmp_path / "x.obj"), np.zeros((8, 4)), off, idx)
    with pytest.raises(ValueError, match="face_offsets"):
        _core.save_mesh(str(tmp_path / "x.obj"), V, off[:-1], idx)
    with pytest.raises(ValueError, match="face_indices"):
        _core.save_mesh(str(tmp_path / "x.obj"), V, off, idx.reshape(-1, 2))
    _core.save_mesh(str(tmp_path / "x.obj"), V.tolist(), off.tolist(), idx.tolist())
    Vr, offr, idxr = _core.load_mesh(str(tmp_path / "x.obj"))
    assert np.array_equal(Vr, V) and np.array_equal(offr, off) and np.array_equal(idxr, idx)


# ---------------------------------------------------------------- faces_to_csr

def test_faces_to_csr_rectangular_and_lists():
    off, idx = faces_to_csr(np.array([[0, 1, 2], [2, 3, 0]], np.int32), 4)
    assert off.dtype == np.int64 and idx.dtype == np.int64
    assert off.tolist() == [0, 3, 6] and idx.tolist() == [0, 1, 2, 2, 3, 0]
    off, idx = faces_to_csr([[0, 1, 2], [3, 4, 5, 6], (1,)])
    assert off.tolist() == [0, 3, 7, 8] and idx.tolist() == [0, 1, 2, 3, 4, 5, 6, 1]
    off, idx = faces_to_csr([])
    assert off.tolist() == [0] and idx.size == 0
    off, idx = faces_to_csr(np.zeros((0, 3), np.int64))
    assert off.tolist() == [0] and idx.size == 0
    off, idx = faces_to_csr([np.array([0, 1, 2], np.uint64), np.array([2, 1, 0], np.int64)], 3)
    assert idx.dtype == np.int64 and idx.tolist() == [0, 1, 2, 2, 1, 0]


def test_faces_to_csr_errors_name_face_and_index():
    with pytest.raises(ValueError, match=r"face 1 \[2, -1, 0\] has vertex index -1"):
        faces_to_csr(np.array([[0, 1, 2], [2, -1, 0]]))
    with pytest.raises(ValueError, match=r"face 1 \[2, 9, 0\] has vertex index 9.*0 to 3"):
        faces_to_csr(np.array([[0, 1, 2], [2, 9, 0]]), num_vertices=4)
    with pytest.raises(ValueError, match=r"face 2 \[4, 5, 6, 7\] has vertex index 7"):
        faces_to_csr([[0, 1, 2], [1, 2, 3, 4], [4, 5, 6, 7]], 7)
    with pytest.raises(ValueError, match=r"face 0 \[-3\] has vertex index -3"):
        faces_to_csr([[-3]])
    with pytest.raises(ValueError, match="face 1 is empty"):
        faces_to_csr([[0, 1, 2], []])
    with pytest.raises(ValueError, match="at least one vertex"):
        faces_to_csr(np.zeros((2, 0), np.int64))
    with pytest.raises(ValueError, match="shape"):
        faces_to_csr(np.zeros((2, 3, 1), np.int64))
    with pytest.raises(ValueError, match="1-D"):
        faces_to_csr([[[0, 1, 2]]])
    big = np.array([[0, 1, np.iinfo(np.uint64).max]], np.uint64)
    with pytest.raises(ValueError, match="out of range"):
        faces_to_csr(big)


@pytest.mark.parametrize("faces", [np.array([[0.0, 1.0, 2.0]]), [[0.0, 1.0, 2.0]], [[0, 1.5, 2]],
                                   np.array([[True, False, True]]), [["a", "b", "c"]]])
def test_faces_to_csr_rejects_non_integer_dtypes(faces):
    with pytest.raises(TypeError, match="integer"):
        faces_to_csr(faces)


def test_faces_to_csr_rejects_non_sequences():
    with pytest.raises(TypeError):
        faces_to_csr(3)


# ---------------------------------------------------------------- errors from files

def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_mesh(tmp_path / "nope.obj")
    with pytest.raises(FileNotFoundError):
        load_mesh(str(tmp_path / "nope" / "x.ply"))


def test_directory_is_os_error(tmp_path):
    (tmp_path / "d.off").mkdir()
    with pytest.raises(OSError):
        load_mesh(tmp_path / "d.off")


@pytest.mark.parametrize("name", ["t.ply", "t.off"])
def test_truncated_files_are_value_errors(tmp_path, name):
    V, F = random_mesh(2)
    full = tmp_path / ("full" + os.path.splitext(name)[1])
    save_mesh(full, V, F)
    data = full.read_bytes()
    for cut in (len(data) // 3, len(data) // 2, len(data) - 7):
        (tmp_path / name).write_bytes(data[:cut])
        with pytest.raises(ValueError, match=name):
            load_mesh(tmp_path / name)


def test_truncated_obj_vertex_line_is_a_value_error(tmp_path):
    # An OBJ cut at a line boundary is just a smaller valid OBJ; a cut inside a `v` line is not.
    V, F = random_mesh(3)
    save_mesh(tmp_path / "full.obj", V, F)
    data = (tmp_path / "full.obj").read_bytes()
    cut = data.index(b"\nv ", len(data) // 4) + 5
    (tmp_path / "t.obj").write_bytes(data[:cut])
    with pytest.raises(ValueError, match=r"t\.obj:\d+: vertex needs 3 coordinates"):
        load_mesh(tmp_path / "t.obj")


def test_parse_error_names_file_and_line(tmp_path):
    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n")
    with pytest.raises(ValueError, match=r"bad\.obj:4: face vertex index 4 is out of range"):
        load_mesh(p)
    p.write_text("v 0 0 0\nv 1 zero 0\n")
    with pytest.raises(ValueError, match=r"bad\.obj:2: .*'zero'"):
        load_mesh(p)


def test_unknown_extension(tmp_path):
    (tmp_path / "m.stl").write_text("solid")
    with pytest.raises(ValueError, match="format"):
        load_mesh(tmp_path / "m.stl")


# ---------------------------------------------------------------- public meshes

def shared_meshes():
    if not os.path.isdir(SHARED_MESHES):
        return []
    return sorted(f for f in os.listdir(SHARED_MESHES) if f.lower().endswith((".obj", ".ply", ".off")))


@pytest.mark.parametrize("name", shared_meshes() or ["<none>"])
def test_public_meshes_load(name):
    if name == "<none>":
        pytest.skip(f"no public meshes at {SHARED_MESHES}")
    V, F = load_mesh(pathlib.Path(SHARED_MESHES) / name)
    assert V.ndim == 2 and V.shape[1] == 3 and V.shape[0] > 0
    assert np.isfinite(V).all()
    faces = F if isinstance(F, list) else list(F)
    assert len(faces) > 0
    off, idx = faces_to_csr(F, V.shape[0])  # raises if any index is out of range
    assert idx.min() >= 0 and idx.max() < V.shape[0]
    assert off[-1] == idx.size

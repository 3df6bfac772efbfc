"""The core's OpenVDB reader on files Blender's own OpenVDB writes (issue 23): volumes made by
geometry nodes (Volume Cube with an analytic density, Mesh to Volume of a sphere), saved with
VolumeGrids.save, read with pathlight_core.read_vdb and compared voxel by voxel with the analytic
field and with the grids' matrix_object. Blender 4.5's save writes Blosc (LZ4, byte shuffle)
with active-mask compression, full-precision floats; the other codecs and half floats are
covered by tests/core/test_vdb.py with hand-written files. (Mantaflow bakes would give ZIP and
half-float caches, but the bpy 4.5 wheel's Mantaflow aborts the process on bake:
"'LevelsetGrid' object has no attribute 'setConst'", so no fluid cache is used here.)"""
import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core not built")

MIN, MAX, RES = np.array([-1.0, -0.5, 0.25]), np.array([2.0, 1.5, 1.0]), (32, 24, 16)


def core():
    return load_addon().core.get_core()


def analytic(p):
    """x * y + z: the density the Volume Cube's node tree computes from Position."""
    return p[..., 0] * p[..., 1] + p[..., 2]


def volume_object(name, build):
    """A volume object whose geometry nodes tree `build(ng, output_socket)` fills."""
    vol = bpy.data.volumes.new(name)
    ob = bpy.data.objects.new(name, vol)
    bpy.context.scene.collection.objects.link(ob)
    ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    out = ng.nodes.new("NodeGroupOutput")
    build(ng, out.inputs[0])
    ob.modifiers.new("GN", "NODES").node_group = ng
    return ob


def save_evaluated(ob, path):
    ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    grids = ev.data.grids
    assert grids.load()
    mats = {g.name: np.array(g.matrix_object) for g in grids}
    assert grids.save(str(path))
    return mats


@pytest.fixture(scope="module")
def cube_file(tmp_path_factory):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)

    def build(ng, out):
        n = ng.nodes
        cube, pos, sep = n.new("GeometryNodeVolumeCube"), n.new("GeometryNodeInputPosition"), n.new("ShaderNodeSeparateXYZ")
        mul, add = n.new("ShaderNodeMath"), n.new("ShaderNodeMath")
        mul.operation, add.operation = "MULTIPLY", "ADD"
        ng.links.new(pos.outputs[0], sep.inputs[0])
        ng.links.new(sep.outputs[0], mul.inputs[0])
        ng.links.new(sep.outputs[1], mul.inputs[1])
        ng.links.new(mul.outputs[0], add.inputs[0])
        ng.links.new(sep.outputs[2], add.inputs[1])
        ng.links.new(add.outputs[0], cube.inputs["Density"])
        cube.inputs["Min"].default_value = MIN
        cube.inputs["Max"].default_value = MAX
        for axis, r in zip("XYZ", RES):
            cube.inputs[f"Resolution {axis}"].default_value = r
        ng.links.new(cube.outputs[0], out)

    path = tmp_path_factory.mktemp("vdb") / "cube.vdb"
    mats = save_evaluated(volume_object("Cube", build), path)
    return path, mats


def test_volume_cube_header_and_compression(cube_file):
    path, mats = cube_file
    (info,) = core().read_vdb(str(path))
    print("Blender's VolumeGrids.save:", info["file_version"], info["library_version"], info["compression_names"],
          info["tree_type"], "half" if info["half_float"] else "full")
    assert info["file_version"] == 224 and info["library_version"][0] >= 7
    assert info["compression_names"] == ["blosc", "active_mask"] and not info["half_float"]
    assert info["name"] == "density" and info["type"] == "float" and info["class"] == "fog volume"
    # Blender keeps the voxels whose density is not 0 (the background) active: all but one here.
    vals = info["grid"].voxels((0, 0, 0), tuple(r - 1 for r in RES))
    assert info["voxel_count"] == np.count_nonzero(vals) >= np.prod(RES) - 2
    assert info["bbox_min"] == (0, 0, 0) and info["bbox_max"] == tuple(r - 1 for r in RES)
    np.testing.assert_allclose(info["transform"], mats["density"], rtol=1e-6, atol=1e-7)


def test_volume_cube_voxels_match_the_analytic_density(cube_file):
    path, _ = cube_file
    grid = core().read_vdb(str(path))[0]["grid"]
    vals = grid.voxels((0, 0, 0), tuple(r - 1 for r in RES))
    # The Volume Cube node evaluates the field at Min + i (Max - Min) / (res - 1); its grid
    # transform (and matrix_object) put voxel i's centre half a voxel below that point.
    idx = np.stack(np.indices(RES), -1).astype(np.float64)
    p = MIN + idx * (MAX - MIN) / (np.array(RES) - 1)
    np.testing.assert_allclose(vals, analytic(p), rtol=1e-5, atol=1e-5)
    # Trilinear sampling in object space between voxel centres: the field is bilinear in x, y
    # and linear in z, so the interpolation of the voxel values reproduces it there.
    rng = np.random.default_rng(2)
    ijk = rng.uniform(0, np.array(RES) - 1, (200, 3))
    m = grid.transform
    obj = (m[:3, :3] @ ijk.T).T + m[:3, 3]
    np.testing.assert_allclose(grid.sample(obj.astype(np.float32)),
                               analytic(MIN + ijk * (MAX - MIN) / (np.array(RES) - 1)), rtol=2e-4, atol=2e-4)
    # Outside: the background; the majorant bounds the samples.
    assert grid.sample(np.array([[10.0, 10.0, 10.0]], np.float32))[0] == 0.0
    assert np.all(grid.majorant(obj.astype(np.float32)) >= grid.sample(obj.astype(np.float32)))


def test_file_backed_volume_reads_the_same(cube_file):
    """A Volume datablock loading the saved file: grids.frame_filepath names it and its
    matrix_object agrees with the transform the core reads."""
    path, mats = cube_file
    vol = bpy.data.volumes.new("Loaded")
    vol.filepath = str(path)
    assert vol.grids.load()
    assert bpy.path.abspath(vol.grids.frame_filepath) == str(path)
    (info,) = core().read_vdb(bpy.path.abspath(vol.grids.frame_filepath))
    np.testing.assert_allclose(info["transform"], np.array(vol.grids["density"].matrix_object), rtol=1e-6, atol=1e-7)


def test_mesh_to_volume_sphere(tmp_path):
    def build(ng, out):
        sphere, m2v = ng.nodes.new("GeometryNodeMeshUVSphere"), ng.nodes.new("GeometryNodeMeshToVolume")
        sphere.inputs["Radius"].default_value = 0.8
        sphere.inputs["Segments"].default_value = 64
        sphere.inputs["Rings"].default_value = 32
        m2v.resolution_mode = "VOXEL_SIZE"
        m2v.inputs["Voxel Size"].default_value = 0.05
        m2v.inputs["Density"].default_value = 2.0
        ng.links.new(sphere.outputs["Mesh"], m2v.inputs["Mesh"])
        ng.links.new(m2v.outputs[0], out)

    ob = volume_object("Sphere", build)
    ob.location = (5, 0, 0)  # object space is what the file holds
    mats = save_evaluated(ob, tmp_path / "sphere.vdb")
    (info,) = core().read_vdb(str(tmp_path / "sphere.vdb"))
    grid = info["grid"]
    np.testing.assert_allclose(info["transform"], mats[info["name"]], rtol=1e-6, atol=1e-7)
    assert info["compression_names"] == ["blosc", "active_mask"]
    # Inside the sphere the density, outside the background; the active voxels fill a ball.
    inside = np.array([[0, 0, 0], [0.5, 0, 0], [0, -0.5, 0.3]], np.float32)
    outside = np.array([[0.9, 0, 0], [0, 0, 1.0], [2, 2, 2]], np.float32)
    np.testing.assert_allclose(grid.sample(inside, "closest"), 2.0)
    np.testing.assert_allclose(grid.sample(outside, "closest"), 0.0)
    voxel = info["transform"][0, 0]
    assert voxel == pytest.approx(0.05, rel=1e-5)
    ball = 4 / 3 * np.pi * 0.8 ** 3 / voxel ** 3
    assert 0.85 * ball < info["voxel_count"] < 1.15 * ball
    lo = info["transform"][:3, :3] @ np.array(info["bbox_min"]) + info["transform"][:3, 3]
    hi = info["transform"][:3, :3] @ np.array(info["bbox_max"]) + info["transform"][:3, 3]
    np.testing.assert_allclose(lo, -0.8, atol=0.1)
    np.testing.assert_allclose(hi, 0.8, atol=0.1)


def test_truncated_blender_files_raise(cube_file):
    data = cube_file[0].read_bytes()
    pc = core()
    for n in range(16):
        with pytest.raises(RuntimeError):
            pc.read_vdb_bytes(data[: len(data) * n // 16])
    assert pc.read_vdb_bytes(data)[0]["grid"] is not None

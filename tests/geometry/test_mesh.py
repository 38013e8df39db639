import io
import struct
import time

import cv2
import numpy as np
import pytest
import shapely
import trimesh

from app.geometry.mesh import MeshError, load_mesh, mesh_summary, resting_poses, to_glb, volume_and_centroid
from app.geometry.thumbnail import render_mesh_rgba, render_thumbnail
from app.geometry.transforms import check_pose, transform_points


def box(extents=(40.0, 20.0, 10.0), offset=(5.0, -3.0, 2.0)):
    return trimesh.creation.box(extents=extents).apply_translation(offset)


# ----------------------------------------------------------------------------- formats

@pytest.mark.parametrize("suffix, file_type", [
    (".stl", "stl"), (".STL", "stl_ascii"), (".obj", "obj"), (".ply", "ply"), (".glb", "glb"),
])
def test_every_mesh_format_round_trips_a_box_in_mm(suffix, file_type):
    ref = box()
    data = ref.export(file_type=file_type)
    if isinstance(data, str):
        data = data.encode()
    m = load_mesh(data, "part" + suffix, "mm")
    assert np.allclose(m.bounds, ref.bounds, atol=1e-4)  # frame kept, not recentred
    assert len(m.faces) == 12 and m.is_watertight
    assert m.metadata["units_source"] == "caller"


def test_gltf_with_embedded_buffers():
    ref = box()
    data = trimesh.Scene(ref).export(file_type="gltf", embed_buffers=True)
    data = data["model.gltf"] if isinstance(data, dict) else data
    m = load_mesh(data if isinstance(data, bytes) else data.encode(), "part.gltf")
    assert np.allclose(m.bounds, ref.bounds, atol=1e-4)


def test_scene_with_two_bodies_is_concatenated_with_transforms():
    a, b = box((10, 10, 10), (0, 0, 0)), box((10, 10, 10), (0, 0, 0))
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="a")
    scene.add_geometry(b, node_name="b", transform=trimesh.transformations.translation_matrix([100, 0, 0]))
    m = load_mesh(scene.export(file_type="glb"), "two.glb")
    assert len(m.faces) == 24
    assert np.allclose(m.bounds, [[-5, -5, -5], [105, 5, 5]], atol=1e-4)


def test_real_stl_in_inch_is_scaled_to_mm(external_data):
    data = (external_data / "trimesh_models" / "featuretype.STL").read_bytes()
    m = load_mesh(data, "featuretype.STL", "inch")
    s = mesh_summary(m)
    assert np.allclose(s["extents_mm"], [127.0, 63.5, 34.925], atol=1e-3)
    assert s["watertight"] and s["faces"] == 3476
    assert s["volume_mm3"] == pytest.approx(11.628 * 25.4 ** 3, rel=1e-3)  # SOURCES.md: 11.628 in^3


def test_real_step_reads_its_own_inch_unit_into_mm(external_data):
    """featuretype.STEP is an inch part: the STEP declares its unit, so the caller's unit is ignored
    and the result matches the STL of the same part scaled from inch (same frame too)."""
    data = (external_data / "trimesh_models" / "featuretype.STEP").read_bytes()
    m = load_mesh(data, "featuretype.STEP", "mm")
    assert m.metadata["units_source"] == "file"
    stl = load_mesh((external_data / "trimesh_models" / "featuretype.STL").read_bytes(), "f.stl", "inch")
    assert np.allclose(m.bounds, stl.bounds, atol=0.01)
    assert m.is_watertight
    assert abs(m.volume) == pytest.approx(abs(stl.volume), rel=2e-3)


def test_real_step_multi_body_mm_part(external_data):
    data = (external_data / "trimesh_models" / "box_sides.STEP").read_bytes()
    m = load_mesh(data, "box_sides.stp")
    assert np.allclose(np.sort(m.extents), np.sort([184.15, 114.3, 95.25]), atol=0.05)  # SOURCES.md


# ----------------------------------------------------------------------------- rejections

def test_unknown_suffix():
    with pytest.raises(MeshError) as e:
        load_mesh(b"1 2 3", "cloud.xyz")
    assert str(e.value) == "unsupported file type .xyz; use STL, OBJ, PLY, GLB or STEP"
    assert e.value.status == 422


def test_unknown_units():
    with pytest.raises(MeshError, match="unknown units 'm'") as e:
        load_mesh(box().export(file_type="stl"), "a.stl", "m")
    assert e.value.status == 422


@pytest.mark.parametrize("filename, data, reason", [
    ("a.stl", b"this is not an stl file at all" * 5, "could not read STL: no triangles found in the file"),
    ("a.glb", b"glTF\x01\x00\x00\x00" + b"\x00" * 20, "could not read GLB: "),
    ("a.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n", "could not read PLY: the file is malformed or truncated"),
    ("a.gltf", b"{not json", "could not read GLTF: not a JSON document"),
    ("a.step", b"ISO-10303-21;\nthis is broken\n", "could not read STEP: OpenCASCADE failed to parse the file"),
    ("a.obj", b"", "could not read OBJ: the file is empty (0 bytes)"),
])
def test_parse_errors_are_422_with_the_reason(filename, data, reason):
    with pytest.raises(MeshError) as e:
        load_mesh(data, filename)
    assert e.value.status == 422
    assert str(e.value).startswith(reason)
    assert len(str(e.value)) > len("could not read XXX: ")  # a reason follows


def test_gltf_with_external_buffers_says_so():
    files = trimesh.Scene(box()).export(file_type="gltf")
    with pytest.raises(MeshError) as e:
        load_mesh(files["model.gltf"], "model.gltf")
    assert str(e.value).startswith("could not read GLTF: it references external files (gltf_buffer_0.bin")
    assert e.value.status == 422


def test_empty_mesh_binary_and_ascii_stl():
    empty_binary = b"\0" * 80 + struct.pack("<I", 0)
    for data in (empty_binary, b"solid empty\nendsolid empty\n"):
        with pytest.raises(MeshError) as e:
            load_mesh(data, "empty.stl")
        assert str(e.value) == "mesh has 0 faces" and e.value.status == 422


def test_obj_with_vertices_but_no_faces():
    with pytest.raises(MeshError) as e:
        load_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "points.obj")
    assert e.value.status == 422 and str(e.value) == "mesh has 0 faces"


def test_all_degenerate_triangles():
    tri = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 1, 1], [2, 2, 2], [0, 0, 5]], faces=[[0, 1, 2], [0, 1, 1]],
                          process=False)
    with pytest.raises(MeshError) as e:
        load_mesh(tri.export(file_type="stl"), "degenerate.stl")
    assert str(e.value).startswith("mesh has 0 faces") and e.value.status == 422


def test_flat_mesh_names_its_extents():
    plane = trimesh.Trimesh(vertices=[[0, 0, 0], [100, 0, 0], [100, 50, 0], [0, 50, 0]],
                            faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.raises(MeshError) as e:
        load_mesh(plane.export(file_type="stl"), "sheet.stl")
    assert str(e.value).startswith("mesh is flat: extents 100 x 50 x 0 mm")
    assert e.value.status == 422


def test_real_stl_in_metres_is_refused_as_tiny(external_data):
    """octagonal_pocket.stl is unitless, 0.229 x 0.165 x 0.016: metres (SOURCES.md), not mm or inch."""
    data = (external_data / "trimesh_models" / "octagonal_pocket.stl").read_bytes()
    with pytest.raises(MeshError) as e:
        load_mesh(data, "octagonal_pocket.stl", "mm")
    assert str(e.value).startswith("mesh is tiny: extents 0.229 x 0.165 x 0.016 mm")
    assert "metres" in str(e.value) and e.value.status == 422


def test_face_limit_is_413():
    data = trimesh.creation.icosphere(subdivisions=3).export(file_type="stl")  # 1280 faces
    with pytest.raises(MeshError) as e:
        load_mesh(data, "ball.stl", max_faces=1000)
    assert e.value.status == 413
    assert str(e.value).startswith("mesh has 1280 faces; the limit is 1000")
    assert len(load_mesh(data, "ball.stl", max_faces=1280).faces) == 1280


# ----------------------------------------------------------------------------- outputs

def test_glb_is_mm_and_keeps_the_frame():
    m = load_mesh(box().export(file_type="stl"), "a.stl", "inch")
    glb = to_glb(m)
    assert glb[:4] == b"glTF"
    back = load_mesh(glb, "n.glb", "mm")
    assert np.allclose(back.bounds, m.bounds, atol=1e-3)
    assert np.allclose(back.extents, np.array([40, 20, 10]) * 25.4, atol=1e-3)


def test_summary_of_a_box():
    s = mesh_summary(load_mesh(box().export(file_type="stl"), "a.stl"))
    assert s["bbox_min_mm"] == pytest.approx([-15, -13, -3])
    assert s["bbox_max_mm"] == pytest.approx([25, 7, 7])
    assert s["extents_mm"] == pytest.approx([40, 20, 10])
    assert s["faces"] == 12 and s["vertices"] == 8 and s["watertight"]
    assert s["volume_mm3"] == pytest.approx(8000.0)


def test_summary_of_an_open_mesh_has_no_volume():
    m = box()
    m.update_faces(np.arange(10))
    s = mesh_summary(m)
    assert not s["watertight"] and s["volume_mm3"] is None


# ----------------------------------------------------------------------------- resting poses

def check_rests_on_plane(mesh, pose):
    T = check_pose(pose.T_plane_obj)
    z = transform_points(T, mesh.vertices)[:, 2]
    assert z.min() == pytest.approx(0.0, abs=1e-6)
    assert z.max() - z.min() == pytest.approx(pose.height_mm, abs=1e-6)
    com = transform_points(T, volume_and_centroid(mesh.convex_hull if not mesh.is_watertight else mesh)[1])[0]
    assert np.allclose(com[:2], 0.0, atol=1e-6)  # centre of mass above the plane origin
    # stable: the centre of mass projects inside the support polygon (hull points on z = 0)
    hull = transform_points(T, mesh.convex_hull.vertices)
    support = hull[hull[:, 2] < 1e-6, :2]
    assert len(support) >= 3
    assert shapely.MultiPoint(support.tolist()).convex_hull.buffer(1e-6).contains(shapely.Point(0, 0))
    return T


def test_box_has_six_poses_with_probabilities_summing_to_one():
    m = box((40, 20, 10))
    poses = resting_poses(m)
    assert len(poses) == 6
    assert sum(p.probability for p in poses) == pytest.approx(1.0, abs=1e-6)
    heights = sorted(round(p.height_mm, 6) for p in poses)
    assert heights == [10, 10, 20, 20, 40, 40]
    # the flattest pose is the most probable
    assert poses[0].height_mm == pytest.approx(10.0)
    assert poses[0].probability > poses[-1].probability
    for p in poses:
        check_rests_on_plane(m, p)
    assert poses[0].to_dict()["T_plane_obj"][3] == [0, 0, 0, 1]


def test_max_poses_caps_and_renormalises(external_data):
    m = load_mesh((external_data / "trimesh_models" / "featuretype.STL").read_bytes(), "f.stl", "inch")
    poses = resting_poses(m, max_poses=3)
    assert len(poses) == 3 and sum(p.probability for p in poses) == pytest.approx(1.0)
    assert poses[0].height_mm == pytest.approx(34.925, abs=1e-3)  # lies flat most often
    for p in poses:
        check_rests_on_plane(m, p)


@pytest.mark.parametrize("builder", ["machine_vise", "strap_clamp", "bracket_140"])
def test_library_parts_rest_stably(builder):
    from app.geometry import parts

    m = getattr(parts, builder)()
    poses = resting_poses(m)
    assert 2 <= len(poses) <= 8
    for p in poses:
        check_rests_on_plane(m, p)


def test_bounding_box_fallback_when_the_pose_search_fails(monkeypatch):
    def broken(*args, **kwargs):
        raise RuntimeError("qhull failed")

    monkeypatch.setattr(trimesh.poses, "compute_stable_poses", broken)
    m = box((40, 20, 10))
    poses = resting_poses(m)
    assert len(poses) == 6 and sum(p.probability for p in poses) == pytest.approx(1.0)
    assert poses[0].height_mm == pytest.approx(10.0)  # largest face (40 x 20) most probable
    for p in poses:
        check_rests_on_plane(m, p)


def test_open_mesh_falls_back_to_the_hull():
    m = box((30, 30, 10))
    m.update_faces(np.arange(10))  # open: two triangles missing
    poses = resting_poses(m)
    assert poses and poses[0].height_mm == pytest.approx(10.0)
    for p in poses:
        check_rests_on_plane(m, p)


# ----------------------------------------------------------------------------- thumbnail

def test_thumbnail_is_a_png_of_the_right_size_and_not_blank():
    png = render_thumbnail(box(), size_px=200)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (200, 200, 3)
    background = np.all(img == (248, 246, 245), axis=2)  # BGR of the default background
    assert 0.1 < 1 - background.mean() < 0.9
    # three visible faces of a box get three different shades
    shades = {tuple(int(v) for v in img[y, x]) for y in range(0, 200, 4) for x in range(0, 200, 4)}
    assert len(shades) >= 4


def test_thumbnail_transparent_background_and_view_direction():
    m = box((100, 10, 10), (0, 0, 0))  # long along x
    top = render_mesh_rgba(m, size_px=100, azimuth_deg=-90, elevation_deg=89.9)
    ys, xs = np.nonzero(top[:, :, 3] > 128)
    assert np.ptp(xs) > 5 * np.ptp(ys)  # seen from above, x runs across the image
    png = render_thumbnail(m, size_px=64, background_rgb=None)
    rgba = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert rgba.shape == (64, 64, 4) and rgba[0, 0, 3] == 0 and rgba[:, :, 3].max() == 255


def test_zbuffer_hides_the_far_body():
    near = box((20, 20, 20), (0, -50, 0))  # nearer to a viewer on the -y side
    far = box((20, 20, 20), (0, 50, 0))
    both = trimesh.util.concatenate([near, far])
    front = render_mesh_rgba(both, size_px=80, azimuth_deg=-90, elevation_deg=0)
    only_near = render_mesh_rgba(near, size_px=80, azimuth_deg=-90, elevation_deg=0)
    assert np.array_equal(front[:, :, 3] > 0, only_near[:, :, 3] > 0)


@pytest.mark.slow
def test_big_upload_pipeline_is_fast():
    """A 200k-face mesh: load, summary, resting poses, thumbnail, GLB within a few seconds."""
    ball = trimesh.creation.icosphere(subdivisions=6, radius=50)  # 81920 faces
    ring = trimesh.creation.annulus(r_min=20, r_max=60, height=30, sections=15000)
    mesh = trimesh.util.concatenate([ball, ring.apply_translation([150, 0, 0])])
    data = mesh.export(file_type="stl")
    assert len(mesh.faces) > 200_000
    t0 = time.perf_counter()
    m = load_mesh(data, "big.stl")
    mesh_summary(m)
    poses = resting_poses(m)
    png = render_thumbnail(m)
    glb = to_glb(m)
    dt = time.perf_counter() - t0
    assert poses and png[:4] == b"\x89PNG" and glb[:4] == b"glTF"
    assert dt < 12.0, f"took {dt:.1f} s"


def test_glb_bytes_load_back_with_trimesh_directly():
    glb = to_glb(box())
    scene = trimesh.load(io.BytesIO(glb), file_type="glb", force="scene")
    assert len(scene.geometry) == 1

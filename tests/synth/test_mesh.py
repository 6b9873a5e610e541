"""Tests of polcam.synth.mesh: OBJ loading, normalisation, the icosphere and the rasteriser.

References are independent of the code under test: hand-written OBJ files,
closed-form ray/sphere and ray/plane intersections, and convexity bounds.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from polcam.errors import PolcamError
from polcam.synth.mesh import Camera, Mesh, icosphere, load_mesh, load_obj, rasterize, rotation_matrix

REPO = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ helpers
def pixel_rays(focal: float, distance: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera centre and unit rays through pixel centres, written from the documented pinhole model."""
    f = focal * n
    c = np.arange(n) + 0.5
    x = (c[None, :] - n / 2) / f * np.ones((n, 1))
    y = -(c[:, None] - n / 2) / f * np.ones((1, n))
    d = np.stack([x, y, -np.ones((n, n))], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.array([0.0, 0.0, distance]), d


def sphere_hit(center: np.ndarray, rays: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Whether each ray hits the origin-centred sphere, and the ray parameter of the first hit."""
    b = rays @ center  # C . d
    disc = b * b - (center @ center - radius**2)
    hit = disc >= 0
    t = -b - np.sqrt(np.where(hit, disc, 0.0))
    return hit, t


def inradius(mesh: Mesh) -> float:
    """Smallest distance from the origin to a face plane (the inscribed ball of a convex mesh)."""
    n = mesh.face_normals()
    p0 = mesh.vertices[mesh.faces[:, 0]]
    return float(np.abs(np.einsum("ij,ij->i", n, p0)).min())


# --------------------------------------------------------------------- OBJ
def test_load_obj_parses_vertices_faces_fans_and_index_forms(tmp_path: Path) -> None:
    text = """# a comment
o thing
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vn 0 0 1
vt 0 0
f 1/1/1 2/1/1 3/1/1 4/1/1
v 0 0 1
f -1 1//1 2
s off
"""
    p = tmp_path / "quad.obj"
    p.write_text(text)
    m = load_obj(p)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]])
    # the quad becomes the fan (1,2,3), (1,3,4); "-1" is the latest vertex (index 4, 0-based)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3], [4, 0, 1]])
    assert m.name == "quad"


def test_load_obj_reads_gzip(tmp_path: Path) -> None:
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    (tmp_path / "t.obj").write_text(text)
    (tmp_path / "t.obj.gz").write_bytes(gzip.compress(text.encode()))
    a, b = load_obj(tmp_path / "t.obj"), load_obj(tmp_path / "t.obj.gz")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("v 0 0\nf 1 1 1\n", "line 1"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4"),
        ("v 0 0 0\nv 1 0 0\nf 1 2 3\n", "out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "at least 3"),
        ("v 0 0 0\n# nothing else\n", "no triangles"),
    ],
)
def test_load_obj_bad_files_name_file_and_problem(tmp_path: Path, text: str, needle: str) -> None:
    p = tmp_path / "bad.obj"
    p.write_text(text)
    with pytest.raises(PolcamError) as info:
        load_obj(p)
    assert "bad.obj" in str(info.value)
    assert needle in str(info.value)


def test_load_obj_missing_file(tmp_path: Path) -> None:
    with pytest.raises(PolcamError, match="nothere.obj"):
        load_obj(tmp_path / "nothere.obj")


def test_load_mesh_unknown_name_lists_choices() -> None:
    with pytest.raises(PolcamError, match="bunny, dragon, armadillo, sphere"):
        load_mesh("teapot")


@pytest.mark.parametrize(("name", "vertices"), [("bunny", 14290), ("dragon", 10002), ("armadillo", 12502)])
def test_fixture_meshes_match_their_sources_and_normalise(name: str, vertices: int) -> None:
    # vertex counts as stated in fixtures/meshes/SOURCES.md
    assert (REPO / "fixtures" / "meshes" / "SOURCES.md").is_file()
    m = load_mesh(name)
    assert len(m.vertices) == vertices
    lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
    np.testing.assert_allclose((lo + hi) / 2, 0, atol=1e-12)
    assert (hi - lo).max() == pytest.approx(1.0)
    assert m.signed_volume() > 0


def test_normalized_rewinds_inward_meshes() -> None:
    s = icosphere(1)
    inward = Mesh(s.vertices * 3 + 5, s.faces[:, ::-1])
    assert inward.signed_volume() < 0
    m = inward.normalized()
    assert m.signed_volume() > 0
    # every face normal points away from the centre of a sphere
    centroid = m.vertices[m.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", m.face_normals(), centroid) > 0)


# --------------------------------------------------------------- icosphere
@pytest.mark.parametrize("k", [0, 1, 3])
def test_icosphere_is_a_closed_sphere(k: int) -> None:
    r = 0.7
    m = icosphere(k, radius=r)
    assert len(m.faces) == 20 * 4**k
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), r, rtol=1e-12)
    edges = np.unique(np.sort(np.concatenate([m.faces[:, [0, 1]], m.faces[:, [1, 2]], m.faces[:, [2, 0]]]), 1), axis=0)
    assert len(m.vertices) - len(edges) + len(m.faces) == 2  # Euler characteristic of a sphere
    # inscribed polytope: volume between the inscribed ball's and the sphere's
    r_in = inradius(m)
    assert 4 / 3 * np.pi * r_in**3 < m.signed_volume() < 4 / 3 * np.pi * r**3


def test_icosphere_rejects_bad_arguments() -> None:
    with pytest.raises(PolcamError, match="subdivisions"):
        icosphere(9)
    with pytest.raises(PolcamError, match="radius"):
        icosphere(1, radius=0)


def test_rotation_matrix() -> None:
    r = rotation_matrix((10, -35, 70))
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(rotation_matrix((0, 0, 90)) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix((90, 0, 0)) @ [0, 1, 0], [0, 0, 1], atol=1e-12)
    # x first, then y: a rotation about x by 90 then y by 90 sends y -> z -> x
    np.testing.assert_allclose(rotation_matrix((90, 90, 0)) @ [0, 1, 0], [1, 0, 0], atol=1e-12)


# -------------------------------------------------------------- rasteriser
@pytest.mark.parametrize("k", [2, 4])
def test_sphere_mask_and_depth_bracketed_by_analytic_spheres(k: int) -> None:
    n, focal, dist, r = 64, 2.0, 2.5, 0.5
    mesh = icosphere(k, radius=r)
    ras = rasterize(mesh, Camera(focal, dist), n)
    c, rays = pixel_rays(focal, dist, n)
    r_in = inradius(mesh)
    hit_out, t_out = sphere_hit(c, rays, r - 1e-9)
    hit_in, t_in = sphere_hit(c, rays, r_in - 1e-9)
    # ball(r_in) inside the polytope inside ball(r)
    assert np.all(ras.mask[hit_in])
    assert not np.any(ras.mask[~sphere_hit(c, rays, r + 1e-9)[0]])
    assert hit_in.sum() > 0.95 * hit_out.sum()
    # depth along the optical axis: between the outer and the inner sphere's first hits
    dz = -rays[..., 2]
    depth = ras.depth.astype(np.float64)
    tol = 1e-5
    assert np.all(depth[hit_in] >= t_out[hit_in] * dz[hit_in] - tol)
    assert np.all(depth[hit_in] <= t_in[hit_in] * dz[hit_in] + tol)
    assert np.all(np.isinf(ras.depth[~ras.mask]))
    # positions lie on the pixel rays
    pos = ras.position.astype(np.float64)[ras.mask] - c
    cross = np.linalg.norm(np.cross(pos, rays[ras.mask]), axis=1)
    assert cross.max() < 1e-5


def test_sphere_normals_close_to_analytic_and_smooth_beats_flat() -> None:
    n, focal, dist, r = 64, 2.0, 2.5, 0.5
    mesh = icosphere(3, radius=r)
    c, rays = pixel_rays(focal, dist, n)
    hit, t = sphere_hit(c, rays, inradius(mesh) - 1e-9)
    p = c + t[..., None] * rays
    true_n = p / np.linalg.norm(p, axis=-1, keepdims=True)
    frontal = hit & (np.einsum("ijk,ijk->ij", true_n, -rays) > 0.5)
    # the interpolated normal lies in the spherical triangle of its three vertex normals, so its
    # angle to the direction of the hit point is at most the longest edge angle; add the shell
    # between inscribed and circumscribed spheres seen at view angles below 60 degrees
    e = mesh.vertices[mesh.faces]
    cosines = np.concatenate([np.einsum("ij,ij->i", e[:, a], e[:, b]) for a, b in ((0, 1), (1, 2), (2, 0))]) / r**2
    bound = np.arccos(cosines.min()) + (r - inradius(mesh)) / 0.5 / inradius(mesh)
    errs = {}
    for mode in ("vertex", "face"):
        ras = rasterize(mesh, Camera(focal, dist), n, normals=mode)
        got = ras.normal.astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(got[ras.mask], axis=1), 1, atol=1e-5)
        ang = np.arccos(np.clip(np.einsum("ijk,ijk->ij", got, true_n), -1, 1))[frontal]
        assert ang.max() <= bound
        errs[mode] = ang.mean()
    assert errs["vertex"] < errs["face"] / 2


def test_triangle_coverage_depth_and_perspective_correct_positions() -> None:
    # a large tilted triangle: the plane z = 0.3 x - 0.2 y
    n, focal, dist = 48, 1.5, 3.0
    v = np.array([[-0.6, -0.5, 0], [0.7, -0.4, 0], [0.1, 0.6, 0]], dtype=np.float64)
    v[:, 2] = 0.3 * v[:, 0] - 0.2 * v[:, 1]
    ras = rasterize(Mesh(v, np.array([[0, 1, 2]])), Camera(focal, dist), n)
    # expected coverage: pixel centres inside the projected triangle (independent projection)
    f = focal * n
    w = dist - v[:, 2]
    u = n / 2 + f * v[:, 0] / w
    vv = n / 2 - f * v[:, 1] / w
    rr, cc = np.mgrid[0:n, 0:n] + 0.5

    def edge(a: int, b: int) -> np.ndarray:
        return (u[b] - u[a]) * (rr - vv[a]) - (vv[b] - vv[a]) * (cc - u[a])

    e0, e1, e2 = edge(0, 1), edge(1, 2), edge(2, 0)
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    np.testing.assert_array_equal(ras.mask, inside)
    assert inside.sum() > 300
    # depth and position: exact ray/plane intersection
    c, rays = pixel_rays(focal, dist, n)
    normal = np.array([0.3, -0.2, -1.0])
    t = -(c @ normal) / (rays @ normal)
    p = c + t[..., None] * rays
    np.testing.assert_allclose(ras.depth[inside], (dist - p[..., 2])[inside], rtol=1e-6)
    np.testing.assert_allclose(ras.position[inside], p[inside], atol=1e-6)
    np.testing.assert_allclose(ras.object_position[inside], p[inside], atol=1e-6)
    # one flat face: the normal is the plane normal, turned to the camera
    expect = -normal / np.linalg.norm(normal)
    np.testing.assert_allclose(ras.normal[inside], np.broadcast_to(expect, (inside.sum(), 3)), atol=1e-6)


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_zbuffer_keeps_the_nearest_surface_whatever_the_order(order: tuple[int, int]) -> None:
    quad = np.array([[-0.4, -0.4], [0.4, -0.4], [0.4, 0.4], [-0.4, 0.4]])
    near = np.c_[quad + 0.1, np.full(4, 0.2)]
    far = np.c_[quad - 0.1, np.full(4, -0.2)]
    parts = [near, far]
    verts = np.concatenate([parts[order[0]], parts[order[1]]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    ras = rasterize(Mesh(verts, faces), Camera(2.0, 2.0), 40)
    near_faces = (0, 1) if order[0] == 0 else (2, 3)
    d = ras.depth[ras.mask]
    # only two depths appear: 1.8 (near) and 2.2 (far)
    assert np.all(np.isclose(d, 1.8, rtol=1e-6) | np.isclose(d, 2.2, rtol=1e-6))
    near_px = np.isclose(ras.depth, 1.8, rtol=1e-6)
    assert np.all(np.isin(ras.face[near_px], near_faces))
    assert near_px.sum() > 100 and (ras.mask & ~near_px).sum() > 50
    # the near quad covers the image centre, though the far quad is also there
    assert near_px[20, 20]


def test_object_transform_maps_back_to_object_frame() -> None:
    m = icosphere(2, radius=0.4)
    rot = rotation_matrix((20, 40, -30))
    ras = rasterize(m.transformed(rot), Camera(), 32, object_transform=(rot, np.zeros(3)))
    world = ras.position.astype(np.float64)[ras.mask]
    obj = ras.object_position.astype(np.float64)[ras.mask]
    np.testing.assert_allclose(obj @ rot.T, world, atol=1e-6)


def test_rasterize_rejects_bad_input() -> None:
    m = icosphere(0, radius=0.5)
    with pytest.raises(PolcamError, match="in front of the camera"):
        rasterize(m, Camera(2.0, 0.4), 16)
    with pytest.raises(PolcamError, match="image size"):
        rasterize(m, Camera(), 0)
    with pytest.raises(PolcamError, match="normals"):
        rasterize(m, Camera(), 16, normals="smooth")
    with pytest.raises(PolcamError, match="focal"):
        Camera(focal=-1)
    with pytest.raises(PolcamError, match="face indices"):
        Mesh(np.zeros((3, 3)), np.array([[0, 1, 3]]))


def test_two_sided_normals_face_the_camera() -> None:
    # an open hemisphere cup seen from inside: back faces must still be shaded facing the viewer
    s = icosphere(3, radius=0.5)
    keep = s.vertices[s.faces].mean(axis=1)[:, 2] < 0  # far half only: we see its inside
    cup = Mesh(s.vertices, s.faces[keep])
    ras = rasterize(cup, Camera(2.0, 2.5), 48)
    assert ras.mask.sum() > 200
    view = np.array([0, 0, 2.5]) - ras.position.astype(np.float64)
    assert np.all(np.einsum("ij,ij->i", ras.normal[ras.mask].astype(np.float64), view[ras.mask]) > 0)

"""The z-buffered pinhole rasteriser: what each pixel centre of a :class:`~polcam.synth.mesh.Camera` sees.

:func:`rasterize` projects a :class:`~polcam.synth.mesh.Mesh`'s triangles and keeps, per pixel
centre, the nearest surface: depth, surface normal (facing the camera), the 3-D point (world and
object coordinates) and the object mask.  Conventions (coordinates, projection, one sample at each
pixel centre, normals) are those of :mod:`polcam.synth.mesh`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from polcam.errors import PolcamError

if TYPE_CHECKING:
    from polcam.synth.mesh import Camera, Mesh

__all__ = ["Raster", "rasterize"]

# Largest number of (triangle, pixel) candidates handled in one vectorised batch.
_BATCH = 1 << 21
#: Least depth (world units) of a vertex in front of the camera plane.
_MIN_DEPTH = 1e-9
#: Projected triangles of smaller signed area (pixels^2) are edge-on and skipped.
_MIN_AREA = 1e-12
#: A pixel centre within this (in barycentric weight) outside a triangle's edge is inside it, so that
#: centres on an edge shared by two triangles are never lost to rounding.
_EDGE_TOLERANCE = 1e-9
#: Interpolated vertex normals shorter than this (opposed normals cancelling) fall back to the face normal.
_MIN_NORMAL = 1e-12


@dataclass
class Raster:
    """What a pixel centre sees: the output of :func:`rasterize`.

    Attributes
    ----------
    depth
        (H, W) float32 depth along the optical axis (``distance - Z``);
        ``inf`` where no surface is hit.
    normal
        (H, W, 3) float32 unit surface normals in world coordinates, facing
        the camera side; 0 where nothing is hit.
    position
        (H, W, 3) float32 world coordinates of the visible point; 0 off the mesh.
    object_position
        (H, W, 3) float32 coordinates of the visible point in the mesh's own
        frame (before ``object_transform``), for solid textures; 0 off the mesh.
    mask
        (H, W) bool, True where a triangle covers the pixel centre.
    face
        (H, W) int64 index of the visible triangle, -1 where none.
    """

    depth: np.ndarray
    normal: np.ndarray
    position: np.ndarray
    object_position: np.ndarray
    mask: np.ndarray
    face: np.ndarray


def _candidates(u: np.ndarray, v: np.ndarray, height: int, width: int):
    """Bounding boxes of projected triangles in pixel-centre indices."""
    c0 = np.clip(np.ceil(u.min(axis=1) - 0.5), 0, width).astype(np.int64)
    c1 = np.clip(np.floor(u.max(axis=1) - 0.5), -1, width - 1).astype(np.int64)
    r0 = np.clip(np.ceil(v.min(axis=1) - 0.5), 0, height).astype(np.int64)
    r1 = np.clip(np.floor(v.max(axis=1) - 0.5), -1, height - 1).astype(np.int64)
    nx = np.maximum(c1 - c0 + 1, 0)
    ny = np.maximum(r1 - r0 + 1, 0)
    return c0, r0, nx, ny


def rasterize(
    mesh: Mesh,
    camera: Camera,
    size: int | tuple[int, int],
    *,
    normals: str = "vertex",
    object_transform: tuple[np.ndarray, np.ndarray] | None = None,
) -> Raster:
    """Rasterise a mesh with a z-buffer: one sample at each pixel centre.

    Parameters
    ----------
    mesh
        Triangles in world coordinates (in front of the camera: every vertex
        at depth ``camera.distance - z > 0``).
    camera
        The pinhole camera.
    size
        ``N`` for an N x N image, or ``(H, W)``.
    normals
        ``"vertex"`` (interpolated vertex normals, smooth shading) or
        ``"face"`` (flat face normals).
    object_transform
        ``(R, t)`` with ``R`` a rotation such that world = ``R @ object + t``;
        ``object_position`` is mapped back through it (identity when ``None``).

    Returns
    -------
    Raster

    Raises
    ------
    PolcamError
        A bad size or normals mode, or a vertex at or behind the camera plane.
    """
    height, width = _image_size(size)
    if normals not in ("vertex", "face"):
        raise PolcamError(f"normals {normals!r}: expected 'vertex' or 'face'")
    verts = mesh.vertices
    u_v, v_v, w_v = camera.project(verts, height, width)
    if np.any(w_v <= _MIN_DEPTH):
        raise PolcamError(
            f"mesh {mesh.name!r} reaches depth {w_v.min():.3g}: every vertex must lie in front of the "
            f"camera (z < camera distance {camera.distance})"
        )
    faces = mesh.faces
    u, v, w = u_v[faces], v_v[faces], w_v[faces]  # (F, 3) each
    area = (u[:, 1] - u[:, 0]) * (v[:, 2] - v[:, 0]) - (u[:, 2] - u[:, 0]) * (v[:, 1] - v[:, 0])
    c0, r0, nx, ny = _candidates(u, v, height, width)
    count = nx * ny
    keep = (count > 0) & (np.abs(area) > _MIN_AREA)
    tri_all = np.nonzero(keep)[0]
    npix = height * width
    best_depth = np.full(npix, np.inf)
    best_face = np.full(npix, -1, dtype=np.int64)
    best_b = np.zeros((npix, 3))
    starts = _batch_starts(count[tri_all])
    for a, b in zip(starts[:-1], starts[1:]):
        tri = tri_all[a:b]
        _zbuffer_batch(tri, (c0, r0, nx, count), (u, v, w, area), width, (best_depth, best_face, best_b))
    hit = best_face >= 0
    depth_img = np.where(hit, best_depth, np.inf).reshape(height, width).astype(np.float32)
    normal, pos, opos = _surface(mesh, camera, hit, best_face, best_b, w, normals, object_transform)
    return Raster(
        depth=depth_img,
        normal=normal.reshape(height, width, 3).astype(np.float32),
        position=pos.reshape(height, width, 3).astype(np.float32),
        object_position=opos.reshape(height, width, 3).astype(np.float32),
        mask=hit.reshape(height, width),
        face=best_face.reshape(height, width),
    )


def _image_size(size: int | tuple[int, int]) -> tuple[int, int]:
    """(H, W) from ``N`` or ``(H, W)``; PolcamError unless both are positive integers."""
    if isinstance(size, (int, np.integer)):
        height = width = int(size)
    else:
        try:
            height, width = (int(s) for s in size)
        except (TypeError, ValueError):
            raise PolcamError(f"image size {size!r}: expected N or (H, W) positive integers") from None
    if height < 1 or width < 1:
        raise PolcamError(f"image size {(height, width)}: expected positive integers")
    return height, width


def _batch_starts(count: np.ndarray) -> list[int]:
    """Starts (and the end) of batches of triangles whose candidate pixels total about ``_BATCH``."""
    csum = np.cumsum(count)
    starts = [0]
    while starts[-1] < len(count):
        base = csum[starts[-1] - 1] if starts[-1] > 0 else 0
        end = int(np.searchsorted(csum, base + _BATCH, side="right"))
        starts.append(max(end, starts[-1] + 1))
    return starts


def _zbuffer_batch(tri: np.ndarray, boxes: tuple[np.ndarray, ...], proj: tuple[np.ndarray, ...], width: int,
                   best: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """Test one batch of triangles at their candidate pixel centres and merge the nearest hits into ``best``.

    ``boxes`` is (c0, r0, nx, count) of :func:`_candidates`, ``proj`` the projected (u, v, w) (F, 3)
    and the signed areas; ``best`` the flat (depth, face, barycentric weights) buffers, updated in
    place.
    """
    c0, r0, nx, count = boxes
    u, v, w, area = proj
    best_depth, best_face, best_b = best
    cnt = count[tri]
    tid = np.repeat(np.arange(len(tri)), cnt)
    first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    k = np.arange(len(tid)) - first[tid]
    t = tri[tid]
    col = c0[t] + k % nx[t]
    row = r0[t] + k // nx[t]
    px, py = col + 0.5, row + 0.5
    uu, vv, ar = u[t], v[t], area[t]
    # edge functions, normalised by the signed area: barycentric weights in the image
    b0 = ((uu[:, 1] - px) * (vv[:, 2] - py) - (uu[:, 2] - px) * (vv[:, 1] - py)) / ar
    b1 = ((uu[:, 2] - px) * (vv[:, 0] - py) - (uu[:, 0] - px) * (vv[:, 2] - py)) / ar
    b2 = 1.0 - b0 - b1
    eps = -_EDGE_TOLERANCE
    inside = (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
    if not inside.any():
        return
    b0, b1, b2 = b0[inside], b1[inside], b2[inside]
    t, pix = t[inside], (row * width + col)[inside]
    ww = w[t]
    inv_w = b0 / ww[:, 0] + b1 / ww[:, 1] + b2 / ww[:, 2]  # 1/depth is affine in the image
    depth = 1.0 / inv_w
    # z-buffer: nearest candidate per pixel, merged with the batches before
    order = np.lexsort((depth, pix))
    pix_s = pix[order]
    head = np.ones(len(order), dtype=bool)
    head[1:] = pix_s[1:] != pix_s[:-1]
    sel = order[head]
    p_sel = pix[sel]
    better = depth[sel] < best_depth[p_sel]
    sel, p_sel = sel[better], p_sel[better]
    best_depth[p_sel] = depth[sel]
    best_face[p_sel] = t[sel]
    best_b[p_sel] = np.stack([b0[sel], b1[sel], b2[sel]], axis=1)


def _surface(mesh: Mesh, camera: Camera, hit: np.ndarray, best_face: np.ndarray, best_b: np.ndarray, w: np.ndarray,
             normals: str, object_transform: tuple[np.ndarray, np.ndarray] | None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal (facing the camera), world and object position of the visible point, (H * W, 3) each; 0 off the mesh.

    Attributes are interpolated with perspective-correct weights ``(b_i / w_i) / sum_j (b_j / w_j)``.
    """
    npix = hit.size
    normal = np.zeros((npix, 3))
    pos = np.zeros((npix, 3))
    opos = np.zeros((npix, 3))
    if not hit.any():
        return normal, pos, opos
    faces = mesh.faces
    fidx = best_face[hit]
    bsc = best_b[hit]
    wf = w[fidx]
    bp = bsc / wf
    bp /= bp.sum(axis=1, keepdims=True)
    tri_v = mesh.vertices[faces[fidx]]  # (N, 3, 3)
    pos_hit = np.einsum("nk,nkd->nd", bp, tri_v)
    fn = mesh.face_normals()[fidx]
    if normals == "vertex":
        vn = mesh.vertex_normals()[faces[fidx]]
        n = np.einsum("nk,nkd->nd", bp, vn)
        ln = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(ln > _MIN_NORMAL, n / np.where(ln > _MIN_NORMAL, ln, 1), fn)
    else:
        n = fn
    # two-sided: flip where the visible face looks away from the camera
    view = camera.center - pos_hit
    back = np.einsum("nd,nd->n", fn, view) < 0
    n[back] = -n[back]
    normal[hit] = n
    pos[hit] = pos_hit
    if object_transform is None:
        opos[hit] = pos_hit
    else:
        r, tr = object_transform
        opos[hit] = (pos_hit - np.asarray(tr, dtype=np.float64)) @ np.asarray(r, dtype=np.float64)
    return normal, pos, opos

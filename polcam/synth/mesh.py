"""Triangle meshes and a z-buffered pinhole rasteriser, in numpy.

The synthetic protocol of the paper (Shakeri & Zhang, section 4.1) renders the
Stanford Bunny, Dragon and Armadillo into depth images through a pinhole
camera and shades them with Blinn-Phong.  This module holds the geometry half:

* :func:`load_obj` reads a Wavefront OBJ (``v`` and ``f`` lines; everything
  else is ignored; ``.obj.gz`` is read through gzip), :func:`load_mesh` finds
  the named meshes shipped in ``fixtures/meshes/``, and :func:`icosphere`
  builds a sphere (for tests and calibration scenes).
* :meth:`Mesh.normalized` centres a mesh's bounding box on the origin and
  scales its largest extent to 1 (the *unit box* ``[-0.5, 0.5]^3``).
* :func:`rasterize` (:mod:`polcam.synth.raster`) projects the triangles through a :class:`Camera` and keeps,
  per pixel centre, the nearest surface: depth, surface normal, the 3-D point
  (world and object coordinates) and the object mask.

Coordinates
-----------
World coordinates are right-handed: x to the right of the image, y up, z
towards the camera.  The camera sits at ``(0, 0, distance)`` and looks down
``-z``; the object is centred on the origin.  A point ``(X, Y, Z)`` at depth
``w = distance - Z`` projects to the continuous pixel position::

    u = W / 2 + f X / w        (column, to the right)
    v = H / 2 - f Y / w        (row, downwards)
    f = focal * W              (focal length in pixels)

Pixel ``(r, c)`` samples the point ``(c + 0.5, r + 0.5)``: one sample per
pixel at its centre, no anti-aliasing.

Normals
-------
Smooth (Phong) shading: the vertex normals are the area-weighted means of the
face normals around each vertex, interpolated across each triangle with
perspective-correct barycentric weights and renormalised (``normals="vertex"``,
the default).  ``normals="face"`` uses the flat face normal instead.  Normals
are oriented outwards (a mesh whose signed volume is negative is flipped), and
shading is two-sided: where the visible face turns its back to the camera (the
inside of the Bunny seen through the holes in its base) the normal is flipped
to face the viewer.
"""

from __future__ import annotations

import gzip
import os
from dataclasses import dataclass
from functools import cached_property, lru_cache
from os import PathLike
from pathlib import Path

import numpy as np

from polcam.errors import PolcamError
from polcam.synth.raster import Raster, rasterize

__all__ = [
    "MESH_NAMES",
    "Camera",
    "Mesh",
    "Raster",
    "icosphere",
    "load_mesh",
    "load_obj",
    "mesh_dirs",
    "rasterize",
    "rotation_matrix",
]

#: Meshes shipped in ``fixtures/meshes/`` (the paper's three objects).
MESH_NAMES: tuple[str, ...] = ("bunny", "dragon", "armadillo")



# --------------------------------------------------------------------------- meshes
@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh (compared by identity).

    Attributes
    ----------
    vertices
        (V, 3) float64 vertex positions.
    faces
        (F, 3) int64 vertex indices (0-based) of each triangle.
    name
        A label (the file stem for loaded meshes).
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise PolcamError(f"mesh {self.name!r}: vertices of shape {v.shape}, expected (V, 3) with V >= 1")
        if not np.all(np.isfinite(v)):
            raise PolcamError(f"mesh {self.name!r}: vertices must be finite numbers")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or not np.issubdtype(f.dtype, np.integer):
            raise PolcamError(
                f"mesh {self.name!r}: faces of shape {f.shape} and dtype {f.dtype}, "
                "expected (F, 3) integers with F >= 1"
            )
        if f.min() < 0 or f.max() >= len(v):
            raise PolcamError(
                f"mesh {self.name!r}: face indices span [{f.min()}, {f.max()}], expected [0, {len(v) - 1}]"
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f.astype(np.int64, copy=False))

    def face_normals(self) -> np.ndarray:
        """Unit normals of the faces, (F, 3) float64 (zero for degenerate faces).

        The direction follows the winding: ``(v1 - v0) x (v2 - v0)``.
        """
        n = self._cross()
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def _cross(self) -> np.ndarray:
        p = self.vertices[self.faces]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])

    def signed_volume(self) -> float:
        """Signed enclosed volume (divergence theorem); positive when faces wind outwards."""
        p = self.vertices[self.faces]
        return float(np.einsum("ij,ij->", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6.0)

    def vertex_normals(self) -> np.ndarray:
        """Area-weighted vertex normals, (V, 3) float64 unit vectors (zero on isolated vertices)."""
        return self._vertex_normals

    @cached_property
    def _vertex_normals(self) -> np.ndarray:
        cross = self._cross()  # length = 2 * area: area weighting for free
        acc = np.zeros_like(self.vertices)
        for k in range(3):
            np.add.at(acc, self.faces[:, k], cross)
        length = np.linalg.norm(acc, axis=1, keepdims=True)
        return np.divide(acc, length, out=np.zeros_like(acc), where=length > 0)

    def normalized(self) -> Mesh:
        """This mesh centred on the origin, its largest bounding-box extent scaled to 1.

        Faces are re-wound if needed so that normals point outwards (positive
        signed volume).
        """
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        extent = float((hi - lo).max())
        if extent <= 0:
            raise PolcamError(f"mesh {self.name!r}: all vertices coincide, cannot normalise")
        v = (self.vertices - (lo + hi) / 2) / extent
        f = self.faces
        m = Mesh(v, f, self.name)
        if m.signed_volume() < 0:
            m = Mesh(v, f[:, ::-1].copy(), self.name)
        return m

    def transformed(self, rotation: np.ndarray, *, translation: tuple[float, float, float] = (0, 0, 0),
                    scale: float = 1.0) -> Mesh:
        """``scale * R @ v + translation`` for every vertex (normals follow)."""
        r = np.asarray(rotation, dtype=np.float64)
        v = scale * self.vertices @ r.T + np.asarray(translation, dtype=np.float64)
        f = self.faces if np.linalg.det(r) * scale > 0 else self.faces[:, ::-1].copy()
        return Mesh(v, f, self.name)


def rotation_matrix(degrees: tuple[float, float, float]) -> np.ndarray:
    """Rotation about x, then y, then z (fixed axes), angles in degrees.

    Returns
    -------
    numpy.ndarray
        (3, 3) ``Rz @ Ry @ Rx``.
    """
    ax, ay, az = np.deg2rad(np.asarray(degrees, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def load_obj(path: str | PathLike[str]) -> Mesh:
    """Read a Wavefront OBJ file (``.obj`` or gzip-compressed ``.obj.gz``).

    Only ``v x y z`` and ``f`` lines are used; polygons are split into
    triangle fans; ``f`` entries may be ``i``, ``i/t``, ``i//n`` or ``i/t/n``
    and negative (relative) indices are allowed.  The mesh is returned as
    stored (see :meth:`Mesh.normalized`).

    Raises
    ------
    PolcamError
        Missing or unreadable file, a malformed ``v``/``f`` line (the line
        number is given), an index out of range, or no triangle at all.
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
        if p.suffix == ".gz":
            raw = gzip.decompress(raw)
        text = raw.decode("utf-8", errors="replace")
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise PolcamError(f"cannot read mesh: {exc}", path=p) from exc
    verts: list[list[float]] = []
    tris: list[tuple[int, int, int]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line.startswith("v "):
            parts = line.split()
            try:
                verts.append([float(parts[1]), float(parts[2]), float(parts[3])])
            except (IndexError, ValueError):
                raise PolcamError(f"line {lineno}: {line.strip()!r} is not 'v x y z'", path=p) from None
        elif line.startswith("f "):
            parts = line.split()[1:]
            try:
                idx = [int(t.split("/")[0]) for t in parts]
            except ValueError:
                raise PolcamError(f"line {lineno}: {line.strip()!r} has a non-integer vertex index",
                                  path=p) from None
            if len(idx) < 3:
                raise PolcamError(f"line {lineno}: a face needs at least 3 vertices, got {len(idx)}", path=p)
            n = len(verts)
            idx = [i - 1 if i > 0 else n + i for i in idx]
            for i in idx:
                if i < 0 or i >= n:
                    raise PolcamError(
                        f"line {lineno}: vertex index out of range (only {n} vertices defined so far)", path=p
                    )
            tris.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    if not verts or not tris:
        raise PolcamError(
            f"no triangles found ({len(verts)} 'v' lines, {len(tris)} triangles): expected an OBJ mesh", path=p
        )
    name = p.name.split(".")[0]
    return Mesh(np.array(verts, dtype=np.float64), np.array(tris, dtype=np.int64), name)


def mesh_dirs() -> list[Path]:
    """Folders searched for named meshes, in order.

    ``$POLCAM_MESH_DIR`` (if set), then ``fixtures/meshes`` of the source
    tree polcam runs from.
    """
    dirs: list[Path] = []
    env = os.environ.get("POLCAM_MESH_DIR")
    if env:
        dirs.append(Path(env))
    dirs.append(Path(__file__).resolve().parents[2] / "fixtures" / "meshes")
    return dirs


@lru_cache(maxsize=16)
def _load_cached(path: str, mtime: float) -> Mesh:
    return load_obj(path)


def load_mesh(name: str | PathLike[str]) -> Mesh:
    """A mesh by name (``bunny``, ``dragon``, ``armadillo``, ``sphere``) or OBJ path, normalised.

    Named meshes are looked up as ``<name>.obj`` or ``<name>.obj.gz`` in
    :func:`mesh_dirs`; ``sphere`` is :func:`icosphere` with 4 subdivisions.
    Loaded files are cached.

    Returns
    -------
    Mesh
        In the unit box (:meth:`Mesh.normalized`).

    Raises
    ------
    PolcamError
        An unknown name (the searched folders are listed) or a bad file.
    """
    text = str(name)
    if text.lower() == "sphere":
        return icosphere(4)
    candidates: list[Path] = []
    if text.lower() in MESH_NAMES:
        for d in mesh_dirs():
            candidates += [d / f"{text.lower()}.obj", d / f"{text.lower()}.obj.gz"]
    else:
        candidates.append(Path(text))
    for c in candidates:
        if c.is_file():
            return _load_cached(str(c.resolve()), c.stat().st_mtime).normalized()
    raise PolcamError(
        f"mesh {text!r} not found (looked for {', '.join(str(c) for c in candidates)}); "
        f"expected one of {', '.join(MESH_NAMES + ('sphere',))} or an OBJ file path"
    )


def icosphere(subdivisions: int = 3, *, radius: float = 0.5) -> Mesh:
    """A sphere centred on the origin: an icosahedron with each face split ``4**subdivisions`` times.

    Every vertex lies on the sphere of the given radius; faces wind outwards.

    Parameters
    ----------
    subdivisions
        0 to 7 (20 * 4**subdivisions faces).
    radius
        Sphere radius, > 0.
    """
    if not (isinstance(subdivisions, (int, np.integer)) and 0 <= subdivisions <= 7):
        raise PolcamError(f"icosphere subdivisions {subdivisions!r}: expected an integer in [0, 7]")
    if not radius > 0:
        raise PolcamError(f"icosphere radius {radius!r}: expected a positive number")
    t = (1 + 5**0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(int(subdivisions)):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq[:, 0]] + v[uniq[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(3, -1) + len(v)  # midpoints of edges 01, 12, 20 of every face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        m01, m12, m20 = m
        f = np.concatenate([np.stack([a, m01, m20], 1), np.stack([b, m12, m01], 1),
                            np.stack([c, m20, m12], 1), np.stack([m01, m12, m20], 1)])
        v = np.concatenate([v, mid])
    mesh = Mesh(v * radius, f, "sphere")
    if mesh.signed_volume() < 0:
        mesh = Mesh(v * radius, f[:, ::-1].copy(), "sphere")
    return mesh


# ------------------------------------------------------------------------ camera
@dataclass(frozen=True)
class Camera:
    """A pinhole camera at ``(0, 0, distance)`` looking down ``-z``, y up.

    Attributes
    ----------
    focal
        Focal length in units of the image width (``f = focal * W`` pixels);
        the horizontal field of view is ``2 atan(1 / (2 focal))``.
    distance
        Distance from the camera centre to the world origin, > 0.
    """

    focal: float = 2.0
    distance: float = 2.5

    def __post_init__(self) -> None:
        if not (np.isfinite(self.focal) and self.focal > 0):
            raise PolcamError(f"camera focal length {self.focal!r}: expected a positive number (image widths)")
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise PolcamError(f"camera distance {self.distance!r}: expected a positive number")

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, (3,)."""
        return np.array([0.0, 0.0, self.distance])

    def project(self, points: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous pixel coordinates of world points.

        Parameters
        ----------
        points
            (..., 3) world coordinates.

        Returns
        -------
        u, v, w
            Column and row positions (pixel centres at integer + 0.5) and
            depth ``distance - Z`` (positive in front of the camera).
        """
        p = np.asarray(points, dtype=np.float64)
        w = self.distance - p[..., 2]
        f = self.focal * width
        with np.errstate(divide="ignore", invalid="ignore"):
            u = width / 2 + f * p[..., 0] / w
            v = height / 2 - f * p[..., 1] / w
        return u, v, w

    def rays(self, height: int, width: int) -> np.ndarray:
        """Unit viewing directions from the camera centre through every pixel centre, (H, W, 3)."""
        f = self.focal * width
        x = (np.arange(width) + 0.5 - width / 2) / f
        y = -(np.arange(height) + 0.5 - height / 2) / f
        d = np.stack(np.broadcast_arrays(x[None, :], y[:, None], -np.ones((1, 1))), axis=-1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

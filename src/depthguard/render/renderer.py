"""Expected depth images: :func:`render_depth` and the reusable :class:`Renderer` (R16).

The known scene (static CAD meshes and the robot's link meshes at its current
joint values, in world coordinates) is rendered into a camera with a z-buffer:
transform (equation 1), cull back faces, clip against the near plane,
project (equation 2), rasterise with perspective-correct depth, keep the
nearest. See :mod:`depthguard.render.raster` for the kernels and the fill
rule; :mod:`depthguard.render.raster_ref` is their plain-numpy twin.

Output: ``depth`` (H, W) float32 metres, the camera-frame ``z`` of the
nearest surface (not the ray length), 0 where nothing is hit; ``labels``
(H, W) int32, the index into the input list of the mesh that owns the
pixel, -1 where nothing is hit.
"""

from __future__ import annotations

from typing import Sequence

import numba
import numpy as np

from depthguard.geometry.mesh import Mesh, as_mesh
from depthguard.render.raster import render_packed, render_packed_parallel

__all__ = ["Renderer", "render_depth"]


def _read_only(a: np.ndarray) -> np.ndarray:
    v = a.view()
    v.flags.writeable = False
    return v


def _checked(m, k: int) -> Mesh:
    """A :class:`Mesh` with float64 (V, 3) vertices and int32 (F, 3) faces. A ``Mesh`` that
    already has them passes as is (the kernel then checks values: finite vertices and
    face indices in range); anything else goes through :func:`as_mesh`."""
    if type(m) is Mesh:
        v, f = m
        if (isinstance(v, np.ndarray) and isinstance(f, np.ndarray) and v.dtype == np.float64
                and f.dtype == np.int32 and v.ndim == 2 and f.ndim == 2
                and v.shape[1] == 3 and f.shape[1] == 3):
            return m
    return as_mesh(m, name=f"meshes[{k}]")


def _mesh_list(meshes) -> list[Mesh]:
    if isinstance(meshes, Mesh) or (hasattr(meshes, "vertices") and hasattr(meshes, "faces")):
        meshes = [meshes]   # a single mesh
    try:
        items = list(meshes)
    except TypeError:
        raise ValueError(f"meshes must be a list of meshes (Mesh, (vertices, faces) or trimesh), "
                         f"got {type(meshes).__name__}") from None
    return [_checked(m, k) for k, m in enumerate(items)]


class Renderer:
    """Z-buffer renderer for one camera with buffers reused across calls (R16).

    Parameters
    ----------
    cam : Camera
        Intrinsics, image size and pose (``cam.R``, ``cam.t`` = camera_from_world).
    near : float
        Near clipping plane in metres (> 0). Triangles crossing it are clipped,
        not dropped; what lies nearer than ``near`` is not drawn.
    parallel : bool
        Use numba threads (faces in parallel, then disjoint bands of image
        rows). Off by default: one core is steadier when the machine is shared
        (several cameras are better rendered in parallel at a higher level).
    n_bands : int, optional
        Bands of rows for the parallel kernel (default 4 per numba thread).
    ids : bool
        Draw the labels and face ids (default). False: a depth-only renderer (one core;
        ``labels`` and ``face_ids`` are None): the same depth and spans with a third less memory
        traffic per drawn pixel — a simulated camera's moving layers (issue 29).

    The depth / label images and the packed vertex / face / label buffers are
    allocated once and grown when a call brings more triangles; the kernels
    allocate nothing. :meth:`render` returns **read-only views of the renderer's own
    buffers** (``self.depth``, ``self.labels``): the next call overwrites them,
    so copy what you keep. ``self.face_ids`` holds the packed index of the face
    owning each pixel (see :meth:`face_index` for the index within its mesh).
    A call reads out only each row's span of the pixels its triangles and the last
    call's cover (outside it the images hold 0 / -1 already): the views are read-only
    so that nothing else can write there. ``self.spans`` (H, 2) int32 (read-only) holds
    per row the span ``[a, b)`` of the last call's pixels (``(0, 0)``: none): outside
    it the row's depth is 0 (a layer's spans, :class:`~depthguard.sources.layered.LayeredCamera`). One renderer per thread: its buffers are
    not shared safely.
    """

    def __init__(self, cam, near: float = 0.01, parallel: bool = False, n_bands: int | None = None,
                 ids: bool = True):
        try:
            near = float(near)
        except (TypeError, ValueError):
            raise ValueError(f"near must be a distance in metres (got {near!r})") from None
        if not np.isfinite(near) or near <= 0.0:
            raise ValueError(f"near must be a finite distance > 0 m (got {near})")
        for attr in ("R", "t", "fx", "fy", "cx", "cy", "width", "height"):
            if not hasattr(cam, attr):
                raise ValueError(f"cam must be a depthguard Camera (missing {attr!r})")
        self.cam = cam
        self.near = near
        self.parallel = bool(parallel)
        H, W = int(cam.height), int(cam.width)
        if n_bands is None:
            # a few bands per thread: load balance without scanning the triangle list too often
            n_bands = 4 * numba.get_num_threads()
        self.n_bands = int(max(1, min(n_bands, H)))
        self._R = np.ascontiguousarray(cam.R, dtype=np.float64)
        self._t = np.ascontiguousarray(cam.t, dtype=np.float64)
        # the kernels write these; the public images are read-only views of them, because a
        # call reads out only the window its triangles and the last call's touch
        self.ids = bool(ids)
        if not self.ids:
            self.parallel = False           # the depth-only kernel is the serial one
        ih, iw = (H, W) if self.ids else (1, 1)     # depth-only: the kernel's id buffers are never touched
        self._depth = np.zeros((H, W), dtype=np.float32)
        self._labels = np.full((ih, iw), -1, dtype=np.int32)
        self._face_ids = np.full((ih, iw), -1, dtype=np.int32)
        self.depth = _read_only(self._depth)
        self.labels = _read_only(self._labels) if self.ids else None
        self.face_ids = _read_only(self._face_ids) if self.ids else None
        # per row the span [a, b) of the last call's pixels (outside it: 0 / -1), and the kernel's scratch
        self._spans = np.zeros((H, 2), dtype=np.int32)
        self._rows = np.zeros((H, 2), dtype=np.int32)
        self.spans = _read_only(self._spans)
        self._wbuf = np.zeros((H, W))                       # 1/z z-buffer (workspace, clear between calls)
        self._sbuf = np.full((ih, iw), -1, dtype=np.int32)  # winning slot (workspace)
        # the kernels read mesh_off only, and every caller's is read-only (render_arrays': a view):
        # one compiled signature of each kernel instead of two (a read-only array is a type of its
        # own to numba: 17 + 40 CPU-s more on a fresh clone, R29)
        self._mesh_off = _read_only(np.zeros((1, 2), dtype=np.int64))
        self._vw = np.zeros((0, 3))
        self._vc = np.zeros((0, 6))
        self._faces = np.zeros((0, 3), dtype=np.int32)
        self._face_label = np.zeros(0, dtype=np.int32)
        self._tri = np.zeros((0, 18))                       # the parallel kernel's slots
        self._box = np.zeros((0, 4), dtype=np.int32)
        self._bound = None                                  # (n_v, n_f, n_meshes, meshes) of bind()
        self._off_checked = None                            # the read-only mesh_off render_arrays checked

    # -------------------------------------------------------------- buffers
    def _reserve(self, n_v: int, n_f: int) -> None:
        if n_v > len(self._vw):
            cap = max(n_v, 2 * len(self._vw), 1024)
            self._vw = np.zeros((cap, 3))
        if n_f > len(self._faces):
            cap = max(n_f, 2 * len(self._faces), 1024)
            self._faces = np.zeros((cap, 3), dtype=np.int32)
        self._reserve_work(n_v, n_f)

    def _reserve_work(self, n_v: int, n_f: int) -> None:
        """The kernel's workspace for ``n_v`` vertices and ``n_f`` faces (grown, never shrunk)."""
        if n_v > len(self._vc):
            self._vc = np.zeros((max(n_v, 2 * len(self._vc), 1024), 6))
        if n_f > len(self._face_label):
            cap = max(n_f, 2 * len(self._face_label), 1024)
            self._face_label = np.zeros(cap, dtype=np.int32)
            if self.parallel:
                self._tri = np.zeros((2 * cap, 18))
                self._box = np.zeros((2 * cap, 4), dtype=np.int32)

    def _pack(self, meshes: list[Mesh]) -> tuple[int, int]:
        nv = [len(m.vertices) for m in meshes]
        nf = [len(m.faces) for m in meshes]
        self._mesh_off = np.zeros((len(meshes) + 1, 2), dtype=np.int64)
        np.cumsum(nv, out=self._mesh_off[1:, 0])
        np.cumsum(nf, out=self._mesh_off[1:, 1])
        self._mesh_off.flags.writeable = False         # as render_arrays' (one kernel signature)
        n_v, n_f = int(self._mesh_off[-1, 0]), int(self._mesh_off[-1, 1])
        self._reserve(n_v, n_f)
        if n_v:
            np.concatenate([m.vertices for m in meshes], out=self._vw[:n_v])
        if n_f:
            np.concatenate([m.faces for m in meshes], out=self._faces[:n_f])
        return n_v, n_f

    # ------------------------------------------------- fixed topology (R16)
    def bind(self, meshes: Sequence) -> np.ndarray:
        """Pack the faces of ``meshes`` once, for :meth:`render_bound`; returns the (V, 3)
        float64 buffer of their packed vertices (all meshes one after the other), which the
        caller fills with world vertices before each :meth:`render_bound` (e.g.
        :meth:`~depthguard.robot.RobotModel.render_link_vertices`). A :meth:`render` call
        unbinds."""
        ms = _mesh_list(meshes)
        n_v, n_f = self._pack(ms)
        self._bound = (n_v, n_f, len(ms), ms)
        return self._vw[:n_v]

    def render_bound(self, cull_back: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render` of the bound meshes with the vertices now in :meth:`bind`'s buffer:
        the same images as :meth:`render` of those meshes, without packing them again."""
        if self._bound is None:
            raise RuntimeError("render_bound() needs bind(meshes) first")
        n_v, n_f, n_m, ms = self._bound
        status = self._draw(n_v, n_f, n_m, bool(cull_back))
        if status != 0:
            if status == 1:
                for k, m in enumerate(ms):   # as_mesh names the mesh and the problem
                    as_mesh(m, name=f"meshes[{k}]")
            raise ValueError("meshes: " + ("a face index lies outside its mesh" if status == 1
                                           else "vertices must be finite"))
        return self.depth, self.labels

    # ------------------------------------------------- packed by the caller
    def render_arrays(self, vertices: np.ndarray, faces: np.ndarray, mesh_off: np.ndarray,
                      cull_back: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render` of meshes the caller keeps packed (R16): ``vertices`` (V, 3) float64 m
        world and ``faces`` (F, 3) int32 (indices local to their mesh) of all meshes one after
        the other, ``mesh_off`` (M + 1, 2) int64 the first vertex and face of each mesh and the
        totals (e.g. :class:`~depthguard.sim.posed.PackedMeshes`), all C-contiguous. The kernel
        reads them where they are: nothing is packed or copied (the same images as
        :meth:`render` of those meshes). Labels index the packed meshes."""
        if not (isinstance(vertices, np.ndarray) and vertices.dtype == np.float64 and vertices.ndim == 2
                and vertices.shape[1] == 3 and vertices.flags.c_contiguous):
            raise ValueError("vertices must be a C-contiguous float64 (V, 3) array")
        if not (isinstance(faces, np.ndarray) and faces.dtype == np.int32 and faces.ndim == 2
                and faces.shape[1] == 3 and faces.flags.c_contiguous):
            raise ValueError("faces must be a C-contiguous int32 (F, 3) array")
        if mesh_off is not self._off_checked:           # a read-only mesh_off checked once (it cannot change)
            if not (isinstance(mesh_off, np.ndarray) and mesh_off.dtype == np.int64 and mesh_off.ndim == 2
                    and mesh_off.shape[1] == 2 and len(mesh_off) >= 1 and mesh_off.flags.c_contiguous
                    and np.all(np.diff(mesh_off, axis=0) >= 0) and mesh_off[0, 0] == 0 and mesh_off[0, 1] == 0):
                raise ValueError("mesh_off must be a C-contiguous int64 (M + 1, 2) array of increasing "
                                 "offsets from 0 within the vertices and faces")
            if not mesh_off.flags.writeable and mesh_off.base is None:
                self._off_checked = mesh_off
        if not (0 <= mesh_off[-1, 0] <= len(vertices) and 0 <= mesh_off[-1, 1] <= len(faces)):
            raise ValueError("mesh_off must be a C-contiguous int64 (M + 1, 2) array of increasing "
                             "offsets from 0 within the vertices and faces")
        self._bound = None
        n_v, n_f = int(mesh_off[-1, 0]), int(mesh_off[-1, 1])
        self._reserve_work(n_v, n_f)
        self._mesh_off = mesh_off if not mesh_off.flags.writeable else _read_only(mesh_off)
        status = self._draw(n_v, n_f, len(mesh_off) - 1, bool(cull_back), vertices, faces)
        if status != 0:
            raise ValueError("meshes: " + ("a face index lies outside its mesh" if status == 1
                                           else "vertices must be finite"))
        return self.depth, self.labels

    # --------------------------------------------------------------- render
    def render(self, meshes: Sequence, cull_back: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Render ``meshes`` (world coordinates) into the camera (R16).

        Parameters
        ----------
        meshes : list of :class:`~depthguard.geometry.mesh.Mesh`, ``(vertices (V, 3), faces (F, 3))``
            pairs or ``trimesh.Trimesh``; faces wound counter-clockwise seen from outside.
        cull_back : bool
            Skip triangles seen from behind (default). Turn off for open or
            inconsistently wound meshes.

        Returns
        -------
        depth : (H, W) float32 view of ``self.depth``; metres along the optical axis, 0 = nothing.
        labels : (H, W) int32 view of ``self.labels``; index into ``meshes``, -1 = nothing.
        """
        ms = _mesh_list(meshes)
        self._bound = None
        n_v, n_f = self._pack(ms)
        status = self._draw(n_v, n_f, len(ms), bool(cull_back))
        if status != 0:
            for k, m in enumerate(ms):   # as_mesh names the mesh and the problem
                as_mesh(m, name=f"meshes[{k}]")
            raise ValueError("meshes: " + ("a face index lies outside its mesh" if status == 1
                                           else "vertices must be finite"))
        return self.depth, self.labels

    def _draw(self, n_v: int, n_f: int, n_meshes: int, cull_back: bool, vw=None, faces=None) -> int:
        """Run the kernel on the packed buffers (the renderer's own, or ``vw``, ``faces``); its
        status (0 = drawn; else nothing was drawn and the images are cleared)."""
        c = self.cam
        vw = self._vw if vw is None else vw
        faces = self._faces if faces is None else faces
        args = (vw, n_v, faces, n_f, self._mesh_off, n_meshes, self._face_label,
                self._R, self._t, float(c.fx), float(c.fy), float(c.cx), float(c.cy), self.near,
                cull_back, self._vc)
        if self.parallel:
            status, _, _ = render_packed_parallel(*args, self._tri, self._box, self.n_bands, self._wbuf,
                                                  self._sbuf, self._depth, self._labels, self._face_ids,
                                                  self._rows, self._spans)
        else:
            status, _, _ = render_packed(*args, self._wbuf, self._sbuf, self._depth, self._labels,
                                         self._face_ids, self._rows, self._spans, self.ids)
        if status != 0:     # nothing was drawn (the z-buffer is clear); clear what the last call drew
            self._depth[:] = 0.0
            self._labels[:] = -1
            self._face_ids[:] = -1
            self._spans[:] = 0
        return status

    def face_index(self) -> np.ndarray:
        """(H, W) int32: which face of mesh ``labels[v, u]`` owns each pixel of the last
        :meth:`render` (row of that mesh's ``faces``), -1 where nothing. Allocates; not for hot loops."""
        if not self.ids:
            raise RuntimeError("a depth-only Renderer (ids=False) draws no face ids")
        out = np.full(self.face_ids.shape, -1, dtype=np.int32)
        hit = self.face_ids >= 0
        out[hit] = self.face_ids[hit] - self._mesh_off[self.labels[hit], 1]
        return out


def render_depth(cam, meshes: Sequence, near: float = 0.01, labels: bool = False,
                 cull_back: bool = True):
    """Expected depth image of ``meshes`` seen by ``cam`` (R16, SPEC §9).

    Parameters
    ----------
    cam : Camera
    meshes : list of meshes in world coordinates (``Mesh``, ``(vertices, faces)`` or trimesh).
    near : float
        Near clipping plane, metres (> 0).
    labels : bool
        Also return the label image.
    cull_back : bool
        Cull triangles seen from behind (outward CCW winding).

    Returns
    -------
    depth : (H, W) float32, metres (camera-frame z), 0 where nothing is hit;
    or ``(depth, labels)`` with labels (H, W) int32 = index into ``meshes``, -1 where nothing.
    The images are the caller's own (writable; the renderer's buffers are not kept).

    For repeated rendering into the same camera use :class:`Renderer`, which
    keeps its buffers (and hands out read-only views of them).
    """
    r = Renderer(cam, near=near)
    r.render(meshes, cull_back=cull_back)
    depth, lab = r._depth, r._labels          # the one renderer's own arrays: nothing else holds them
    return (depth, lab) if labels else depth

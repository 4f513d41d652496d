"""OpenCL backend of the ray gain: one ray-marching function (``raycast.cl``) for every method,
on the device of :mod:`nbv_prob_cnn.basics.cl_device` (a GPU if present, else the CPU through pocl).

Two kernels call it: ``view_gain`` sums the ray gains of each origin into its candidate views
in local memory (the planners' path: no per-ray gains in global memory), ``ray_gain`` returns
per-ray gains (poses with their own frusta). Each work-item marches a ray from ``lanes``
neighbouring origins at once (:func:`default_lanes`).

The gain variant (:mod:`nbv_prob_cnn.gain.variant`) is a build option of the same source
(``-DGAIN_ORIGINAL=1`` for ``"original"``): one program per variant, built on first use. The
caller passes the variant's sample offsets (its range) and the sum of its weights. The optional
exact-traversal sampling and ``"returns"`` sensor model of the paper's variant
(:mod:`nbv_prob_cnn.gain.sampling`) are build options too (``-DGAIN_EXACT=1``, ``-DGAIN_SENSOR=1``),
whose extra kernel arguments :class:`MarchOptions` carries; without them every launch is the
paper's.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np

from nbv_prob_cnn.basics.cl_device import cl_runtime
from nbv_prob_cnn.gain.march import MarchOptions, RayMarch
from nbv_prob_cnn.gain.marched_grid import ORIGINAL_BORDER_CODE, linear_indices, march_grid, march_normals
from nbv_prob_cnn.gain.search_bounds import BoundOrder, bound_grid, origin_blocks, surface_bound_grid
from nbv_prob_cnn.gain.variant import ORIGINAL_FOCAL, ORIGINAL_NEAR_HIT, check_variant
from nbv_prob_cnn.gain.view_tables import group_first_samples, group_sets, pad_to, reaching_views, view_table

KERNEL_SOURCE = Path(__file__).with_name("raycast.cl")
#: Kernel modes; ``prob_free`` (an unknown sample counts ``(1 - p) Pr``) only in the original variant.
MODES = {"prob": 0, "ig": 1, "prob_free": 2}

#: Origins per work-group in ``view_gain`` (``lanes`` per work-item).
VIEW_GAIN_LOCAL_SIZE = 16
#: Origins per work-item (vector lanes of the ray march) on a CPU device; 1 on a GPU.
CPU_LANES = 16
LANE_WIDTHS = (1, 2, 4, 8, 16)
#: Most origins per work-item of the ``GAIN_SENSOR`` program: pocl's LLVM aborted the process
#: (SIGABRT) building its 16-lane work-group function on AVX-512 machines (CI, exit 134, and one
#: development machine, where 8 and fewer lanes built); another AVX-512 machine (AMD EPYC) built it.
SENSOR_MAX_LANES = 8
#: Origins per ``view_gain`` launch (bounds the device output buffer).
VIEW_GAIN_ORIGINS_PER_LAUNCH = 1 << 17
#: Origins in the first exactly evaluated batch of ``best_view`` (then doubling).
BEST_VIEW_FIRST_BATCH = 2048
#: Origins per axis of a block of ``best_view`` (one bound per block).
BOUND_BLOCK = 2
#: Most samples per ray whose window ranges the surface blend's bounds by dynamic programming keep
#: in private arrays for the backward pass (``DP_SAMPLES``; longer rays gather them again): 2 x 16
#: lanes x 4 bytes a sample, 33 KB a work-item at 256. 3DT block bounds (6 cells) of 4 grids of
#: ``cnn_surface`` explorations: 0.98 -> 0.78 CPU seconds, the same bounds bit for bit.
DP_KEPT_SAMPLES = 256
#: Fewer origins per block on average: ``best_view`` evaluates all origins exactly.
MIN_ORIGINS_PER_BLOCK = 2.0
#: Relative (and absolute) margin added to the block bounds of ``best_view``.
BOUND_MARGIN = 1e-4


def default_lanes(device) -> int:
    """Origins per work-item for ``device``: :data:`CPU_LANES` on a CPU (pocl runs a work-item's
    loop as scalar code, branching per sample; a vector of lanes marches branch-free, 2x faster
    on 3DU N_rays=16), 1 elsewhere (a GPU runs the work-items themselves in lock step)."""
    import pyopencl as cl

    return CPU_LANES if device.type & cl.device_type.CPU else 1


class OpenCLRayCaster:
    """Compiled kernels plus cached constant buffers for one OpenCL device; ``lanes``: origins
    per work-item (one of :data:`LANE_WIDTHS`; default :func:`default_lanes`)."""

    def __init__(self, lanes: int | None = None) -> None:
        runtime = cl_runtime()
        self._cl = runtime.cl
        self.device, self.context, self.queue = runtime.device, runtime.context, runtime.queue
        self.lanes = default_lanes(self.device) if lanes is None else lanes
        if self.lanes not in LANE_WIDTHS:
            raise ValueError(f"lanes: expected one of {LANE_WIDTHS}, got {lanes!r}")
        self._runtime = runtime
        self._kernels: dict[tuple[str, bool, bool, int, int, int], tuple] = {}
        self._ray_kernel, self._view_kernel = self.kernels("paper")
        self._cache: dict[tuple, object] = {}
        self._last_options: tuple | None = None
        self._last_grid: tuple | None = None

    def program_lanes(self, sensor: bool = False) -> int:
        """Origins per work-item of a program: :attr:`lanes`, at most :data:`SENSOR_MAX_LANES` for
        the ``"returns"`` sensor model's."""
        return min(self.lanes, SENSOR_MAX_LANES) if sensor else self.lanes

    def _launch_lanes(self, options: MarchOptions | None) -> int:
        """:meth:`program_lanes` of the program a launch with ``options`` runs."""
        return self.program_lanes(options is not None and options.flags[1])

    def kernels(
        self,
        variant: str,
        exact: bool = False,
        sensor: bool = False,
        surface_bound: bool = False,
        lanes: int | None = None,
        dp_samples: int = 0,
    ) -> tuple:
        """``(ray_gain, view_gain)`` of the program of gain ``variant`` (built on first use), with
        the exact-traversal and ``"returns"`` options (:class:`MarchOptions`), marching
        :meth:`program_lanes` origins per work-item (``lanes``: that many instead, e.g. 1);
        ``surface_bound``: the program of a surface blend's block bounds (``SURFACE_BOUND``: the largest
        gain over the windows' ranges of ``p``); ``dp_samples``: with it, the launches' samples per ray,
        kept per sample for the backward pass (``DP_SAMPLES``; 0: gathered again)."""
        lanes = self.program_lanes(sensor) if lanes is None else int(lanes)
        key = (variant, bool(exact), bool(sensor), int(bool(surface_bound)), lanes, int(dp_samples))
        if key not in self._kernels:
            options = [f"-DLANES={lanes}"]
            if check_variant(variant) == "original":
                options += ["-DGAIN_ORIGINAL=1", f"-DORIGINAL_FOCAL={ORIGINAL_FOCAL!r}f",
                            f"-DORIGINAL_NEAR_HIT={ORIGINAL_NEAR_HIT!r}f"]  # fmt: skip
            options += ["-DGAIN_EXACT=1"] if exact else []
            options += ["-DGAIN_SENSOR=1"] if sensor else []
            options += ["-DSURFACE_BOUND=1"] if surface_bound else []
            options += [f"-DDP_SAMPLES={int(dp_samples)}"] if dp_samples else []
            program = self._runtime.build(KERNEL_SOURCE, tuple(options))
            self._kernels[key] = (self._cl.Kernel(program, "ray_gain"), self._cl.Kernel(program, "view_gain"))
        return self._kernels[key]

    def _option_args(self, options: MarchOptions | None, padded_shape: tuple[int, int, int]) -> list:
        """The extra kernel arguments of ``options`` (after the kernels' own; none for the paper's);
        the last ones are kept (a search launches many batches with the same options)."""
        if options is None:
            return []
        last = self._last_options
        if last is not None and last[0] is options and last[1] == padded_shape:
            return last[2]
        args: list = []
        if options.exact:
            s = options.samples
            args += [self._constant(s.weights.astype(np.float32)), self._constant(s.counts.astype(np.int32)),
                     self._constant(s.first_at(options.min_range))]  # fmt: skip
        if options.sensor is not None:
            normals = march_normals(np.asarray(options.normals), padded_shape)
            mf = self._cl.mem_flags
            normal_buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=normals)
            d = np.asarray(options.directions, dtype=np.float32)
            directions = np.zeros((d.shape[0], 4), dtype=np.float32)
            directions[:, : d.shape[1]] = d
            args += [normal_buf, np.int32(int(np.prod(padded_shape))), self._constant(directions),
                     np.float32(options.sensor.cos_grazing), np.int32(options.samples.weighted)]  # fmt: skip
        self._last_options = (options, padded_shape, args)  # holds options: its id is not reused
        return args

    def _constant(self, array: np.ndarray):
        """A read-only device copy of ``array``, cached by content."""
        array = np.ascontiguousarray(array)
        key = (array.dtype.str, array.shape, array.tobytes())
        buf = self._cache.get(key)
        if buf is None:
            if len(self._cache) > 16:
                self._cache.clear()  # callers hold the buffers they are using
            mf = self._cl.mem_flags
            buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=array)
            self._cache[key] = buf
        return buf

    def _offsets(self, offsets: np.ndarray, padded_shape: tuple[int, ...], cached: bool = True):
        """The device's linear sample offsets ``(R, T)`` of ``(R, T, dims)`` cell offsets; ``cached``:
        kept by content (:meth:`_constant`; a search launches the same table many times), else a
        buffer of its own (one launch's, e.g. each camera's image rays: hashing them cost more)."""
        offset_index = linear_indices(offsets.reshape(-1, offsets.shape[2]), padded_shape, shift=0)
        if cached:
            return self._constant(offset_index.reshape(offsets.shape[:2]))
        mf = self._cl.mem_flags
        return self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=offset_index)

    def _common(self, code: np.ndarray, origins: np.ndarray, march: RayMarch, cached_offsets: bool = True):
        """Device grid, host grid, linear origins and device linear offsets ``(R, T)`` (``cached_offsets``:
        see :meth:`_offsets`)."""
        code_buf, padded = self._marched(code, _border(march))
        origin_index = linear_indices(origins, padded.shape, shift=1)
        return code_buf, padded, origin_index, self._offsets(march.offsets, padded.shape, cached_offsets)

    def _marched(self, code: np.ndarray, border: float):
        """The device and host copies of :func:`march_grid` of ``code``: the last ones again when
        ``code`` and ``border`` equal the last launch's (a search and the re-ranking of its best
        views by their image rays march one grid: on half-explored 3DT its marched grid, with the
        empty-space distances, cost 26-34 ms). Holds one grid, its copy and its marched grid."""
        last = self._last_grid
        if last is not None and last[1] == border and last[0].shape == code.shape and np.array_equal(last[0], code):
            return last[2], last[3]
        self._last_grid = None  # free the old grid before building the new one
        padded = march_grid(code, border)
        mf = self._cl.mem_flags
        code_buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=padded)
        self._last_grid = (code.copy(), border, code_buf, padded)
        return code_buf, padded

    def forget_grid(self) -> None:
        """Drop the kept marched grid (:meth:`_marched`): the next launch marches its grid anew."""
        self._last_grid = None

    def run(self, code: np.ndarray, origins: np.ndarray, march: RayMarch) -> np.ndarray:
        """Ray gains ``(N, R)`` float32 for the encoded grid ``code`` (:func:`encode_grid`) from
        ``origins``, marching ``march`` (:class:`~nbv_prob_cnn.gain.march.RayMarch`)."""
        n, r = origins.shape[0], march.offsets.shape[0]
        if n == 0:
            return np.empty((n, r), dtype=np.float32)
        code_buf, padded, origin_index, offset_buf = self._common(code, origins, march)
        return self._rays(code_buf, padded, origin_index, offset_buf, march)

    def run_each(self, code: np.ndarray, origins: np.ndarray, march: RayMarch) -> np.ndarray:
        """Ray gains ``(N, R)`` float32 of each origin along its own rays: ``march`` holds ``N * R``
        rays, origin ``i`` marches rows ``i * R .. (i + 1) * R - 1`` (one launch of ``ray_gain``)."""
        n = origins.shape[0]
        if n == 0:
            return np.empty((0, 0), dtype=np.float32)
        code_buf, padded, origin_index, offset_buf = self._common(code, origins, march, cached_offsets=False)
        return self._rays(code_buf, padded, origin_index, offset_buf, march, own_rays=march.offsets.shape[0] // n)

    def _rays(self, code_buf, padded, origin_index, offset_buf, march: RayMarch, own_rays: int = 0) -> np.ndarray:
        """``ray_gain`` on a device grid ``code_buf`` (host copy ``padded``) at linear origins: ``(N, R)``
        with ``R`` the march's rays, or with ``own_rays`` > 0 ``R = own_rays``, origin ``i`` marching
        its own ``own_rays`` consecutive rays of the march (rows ``i * R ..``), on the one-lane program
        (lanes march one ray: a block of lanes on one origin marched it that many times; 3DT, 20
        views x 768 rays: 20.6 ms with 16 lanes, 2.8 ms with one)."""
        cl, mf = self._cl, self._cl.mem_flags
        n = origin_index.shape[0]
        r = own_rays or march.offsets.shape[0]
        lanes = 1 if own_rays else self._launch_lanes(march.options)
        origin_index = pad_to(origin_index, lanes)
        blocks = origin_index.size // lanes
        out = np.empty((blocks, r, lanes), dtype=np.float32)
        origin_buf = cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=origin_index)
        out_buf = cl.Buffer(self.context, mf.WRITE_ONLY, out.nbytes)
        kernel = self.kernels(*march.program, lanes=lanes)[0]
        extra = self._option_args(march.options, padded.shape)  # held until the queue has finished
        args = _march_args(march)
        args[0] = np.int32(r)
        kernel.set_args(code_buf, origin_buf, np.int32(origin_index.size), offset_buf, *args,
                        np.int32(1 if own_rays else 0), out_buf, *extra)  # fmt: skip
        cl.enqueue_nd_range_kernel(self.queue, kernel, (blocks * r,), None)
        cl.enqueue_copy(self.queue, out, out_buf)
        self.queue.finish()
        return np.ascontiguousarray(out.transpose(0, 2, 1).reshape(-1, r)[:n])

    def run_views(
        self,
        code: np.ndarray,
        origins: np.ndarray,
        march: RayMarch,
        membership: np.ndarray,
        local_size: int = VIEW_GAIN_LOCAL_SIZE,
        view_sets: np.ndarray | None = None,
    ) -> np.ndarray:
        """View gains ``(N, V)`` float32: the ray gains of each origin summed over the rays of
        each view (``membership`` is the ``(R, V)`` 0/1 ray-in-view matrix; the original variant:
        sum of hits over sum of hits + miss). ``view_sets``: see :meth:`_views` (None: every view)."""
        code_buf, padded, origin_index, offset_buf = self._common(code, origins, march)
        return self._views(code_buf, padded, origin_index, offset_buf, march, membership, local_size, view_sets)

    def _views(self, code_buf, padded, origin_index, offset_buf, march: RayMarch, membership,
               local_size=VIEW_GAIN_LOCAL_SIZE, view_sets=None, surface_bound=None) -> np.ndarray:  # fmt: skip
        """``view_gain`` on a device grid ``code_buf`` (host copy ``padded``) at linear origins.

        ``view_sets``: None (every view exact) or per origin the views wanted exactly, ``(N, V)``
        booleans: a work-group sums the union of its origins' views and marches only their rays;
        other views get 0 (a lower bound of their gains). ``surface_bound``: the device grid of
        :func:`~nbv_prob_cnn.gain.search_bounds.surface_bound_grid` (block bounds of a surface blend,
        the ``SURFACE_BOUND`` program of :meth:`kernels`)."""
        cl, mf = self._cl, self._cl.mem_flags
        n, r, v = origin_index.shape[0], march.offsets.shape[0], membership.shape[1]
        out = np.empty((n, v), dtype=np.float32)
        if n == 0:
            return out
        start, rays = view_table(membership)
        # local references keep every buffer alive until the queue has finished with it
        start_buf, rays_buf = self._constant(start), self._constant(rays)
        device = self.device  # local_size: origins per work-group, a multiple of lanes
        lanes = self._launch_lanes(march.options)
        words = (2 * r if march.variant == "original" else r) + v  # local floats per origin: rays (+ totals), views
        local_size = int(min(local_size, device.max_work_group_size * lanes, device.local_mem_size // (4 * words)))
        local_size = max(lanes, local_size // lanes * lanes)
        first_sample = group_first_samples(padded, origin_index, local_size)
        every = group_sets(np.ones((1, v), dtype=bool), membership)
        sets = every if view_sets is None else group_sets(view_sets, membership, local_size)
        set_stride = 0 if view_sets is None else sets.shape[1]
        block = min(n, VIEW_GAIN_ORIGINS_PER_LAUNCH // local_size * local_size)
        origin_buf = cl.Buffer(self.context, mf.READ_ONLY, -(-block // local_size) * local_size * 4)
        first_buf = cl.Buffer(self.context, mf.READ_ONLY, -(-block // local_size) * 4)
        set_buf = cl.Buffer(self.context, mf.READ_ONLY, max(every.nbytes, -(-block // local_size) * 4 * set_stride))
        if view_sets is None:
            cl.enqueue_copy(self.queue, set_buf, every)
        out_buf = cl.Buffer(self.context, mf.WRITE_ONLY, block * v * 4)
        bounds = surface_bound is not None
        kept = r_samples if bounds and (r_samples := march.offsets.shape[1]) <= DP_KEPT_SAMPLES else 0
        kernel = self.kernels(*march.program, surface_bound=bounds, dp_samples=kept)[1]
        extra = self._option_args(march.options, padded.shape) + ([] if surface_bound is None else [surface_bound])
        for begin in range(0, n, block):
            count = min(block, n - begin)
            cl.enqueue_copy(self.queue, origin_buf, pad_to(origin_index[begin : begin + count], local_size))
            group, groups = begin // local_size, -(-count // local_size)
            cl.enqueue_copy(self.queue, first_buf, first_sample[group : group + groups])
            if view_sets is not None:
                cl.enqueue_copy(self.queue, set_buf, np.ascontiguousarray(sets[group : group + groups]))
            kernel.set_args(
                code_buf, origin_buf, np.int32(count), offset_buf, *_march_args(march), start_buf, rays_buf,
                np.int32(v), first_buf, set_buf, np.int32(set_stride), np.int32(-(-v // 32)),
                cl.LocalMemory(4 * words * local_size), out_buf, *extra,
            )  # fmt: skip
            cl.enqueue_nd_range_kernel(self.queue, kernel, (groups * local_size // lanes,), (local_size // lanes,))
            cl.enqueue_copy(self.queue, out[begin : begin + count], out_buf)
        self.queue.finish()
        return out

    def block_bounds(
        self, code: np.ndarray, origins: np.ndarray, march: RayMarch, membership: np.ndarray, size: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per origin its block, per block and view an upper bound of ``G_W`` of the block's
        origins: ``(block_of (N,), bounds (B, V))`` (see :meth:`best_view`)."""
        size = BOUND_BLOCK if size is None else size
        return self._block_bounds(march_grid(code), origins, march, membership, size)

    def _block_bounds(self, padded, origins, march: RayMarch, membership, size=BOUND_BLOCK, min_per_block=0.0):
        """``(block_of, bounds)``; bounds None when blocks hold fewer than ``min_per_block``
        origins on average (bounds would cost about as much as exact gains), and for the original
        ``ig``, whose per-ray totals vary (its view gain is a ratio: no bound here)."""
        if march.variant == "original" and march.mode == "ig":
            return np.zeros(origins.shape[0], dtype=np.int64), None
        dims = origins.shape[1]
        grown = np.array([size, size, size if dims == 3 else 0])
        bound_shape = tuple(int(n) for n in np.array(padded.shape) + 2 * grown)
        corners, block_of = origin_blocks(origins, size)
        if corners.shape[0] * min_per_block > origins.shape[0]:
            return block_of, None
        corner_index = linear_indices(corners + grown, bound_shape, shift=0)
        bound = bound_grid(padded, dims, probabilistic=march.mode != "ig", size=size)
        mf = self._cl.mem_flags
        bound_buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=bound)
        # prob_free bounds itself: the least p of a window is below every cell's p (1 - p is above)
        bound_march = dataclasses.replace(march, mode="prob_free" if march.mode == "prob_free" else "prob", eps=0.0,
                                          min_range=0.0)  # fmt: skip
        # a surface blend: the largest gain over the windows' ranges of p, by dynamic programming. Taking
        # the window's largest p for the factor and its smallest for the visibility apart let 62 641 of
        # 111 765 origins of a half-explored 3DT grid through (this: 2 126; CPU time of one search 0.380 ->
        # 0.333 s; 3DU 0.125 -> 0.067 s); on 2D, with blocks of 3 cells, 3 half-explored maps 0.296 s (the
        # former with blocks of 2) -> 0.220 s and 5 exploration grids 0.289 -> 0.205 s
        surface_buf = None
        if march.surface:
            most = surface_bound_grid(padded, dims, size)
            surface_buf = self._cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=most)
        view_bound = self._views(bound_buf, bound, corner_index, self._offsets(march.offsets, bound.shape),
                                 bound_march, membership, surface_bound=surface_buf)  # fmt: skip
        return block_of, view_bound

    def best_view(
        self,
        code: np.ndarray,
        origins: np.ndarray,
        march: RayMarch,
        membership: np.ndarray,
        first_batch: int = BEST_VIEW_FIRST_BATCH,
        block_size: int = BOUND_BLOCK,
        prune_views: bool = True,
    ) -> tuple[int, int, float, int]:
        """The first ``(origin, view)`` of largest ``G_W`` in origin-major order, exactly as the
        exhaustive ``run_views(...)`` argmax, without computing every origin's gains.

        Coarse to fine: the origins are grouped in blocks of ``block_size`` cells per axis; ``view_gain`` on
        :func:`bound_grid` from each block's corner gives, per view, an upper bound of the gain
        of every origin in the block (each sample of the corner's ray covers the samples of the
        block's rays at the same ``t``: it counts the full weight where any of them is unknown,
        is at least as visible (``1 - min p`` per step) and stops only where all of them have
        stopped; ``Pr <= 1`` and ``t >= min_range`` only lower the true gain, also for ``ig``).
        Origins are then evaluated exactly in order of decreasing block bound, in growing
        batches, until the next bound is below the best exact gain (with a float32 rounding
        margin): no pruned origin can beat or tie it. With ``prune_views``, after the first batch
        each origin evaluates only the views whose block bound reaches the best gain so far and
        marches only their rays (see :func:`reaching_views`; the others cannot beat or tie it).
        The original variant (:mod:`~nbv_prob_cnn.gain.variant`): the same bounds hold for its
        probabilistic modes (non-negative weights; every ray of a view has the same ``hits + miss``,
        so a view's gain is its bounded hits over a constant); its ``ig`` evaluates every origin.
        ``march.options`` (:class:`~nbv_prob_cnn.gain.march.MarchOptions`): the bounds are the
        paper's gain on the same samples up to ``r_max``
        (:meth:`~nbv_prob_cnn.gain.march.MarchOptions.bound_options`), which bounds the
        ``"returns"`` gain too.

        Returns:
            ``(origin position, view, gain, origins evaluated exactly)``; ``(0, 0, 0.0, n)`` when no
            view has a positive gain (the exhaustive argmax of all zeros).
        """
        index, view, gain, done = self.best_views(code, origins, march, membership, 1, None, first_batch, block_size,
                                                  prune_views)  # fmt: skip
        if index.size == 0:
            return 0, 0, 0.0, done
        return int(index[0]), int(view[0]), float(gain[0]), done

    def best_views(
        self,
        code: np.ndarray,
        origins: np.ndarray,
        march: RayMarch,
        membership: np.ndarray,
        top_k: int = 1,
        allowed: np.ndarray | None = None,
        first_batch: int = BEST_VIEW_FIRST_BATCH,
        block_size: int = BOUND_BLOCK,
        prune_views: bool = True,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """The ``top_k`` ``(origin, view)`` pairs of largest positive ``G_W``, best first (ties: the
        first origin, then the first view), exactly as the exhaustive ``run_views(...)`` ranking, by
        the coarse-to-fine search of :meth:`best_view` with the ``top_k``-th best gain as the bar a
        block's bound must reach. ``allowed``: ``(N, V)`` bool, the views allowed per origin (the
        others count as zero gain; the bounds still bound the allowed views).

        Returns:
            ``(origin positions, views, gains, origins evaluated exactly)``: at most ``top_k`` each.
        """
        n = origins.shape[0]
        code_buf, padded, origin_index, offset_buf = self._common(code, origins, march)
        options = march.options
        if options is None:
            block_of, view_bound = self._block_bounds(padded, origins, march, membership, block_size,
                                                      MIN_ORIGINS_PER_BLOCK)  # fmt: skip
        else:  # the paper's gain on the same samples, with the border occupied
            bound_padded = padded if _border(march) == -1.0 else march_grid(code)
            bound_march = dataclasses.replace(march, offsets=march.offsets[:, : options.samples.weighted],
                                              options=options.bound_options())  # fmt: skip
            block_of, view_bound = self._block_bounds(bound_padded, origins, bound_march, membership, block_size,
                                                      MIN_ORIGINS_PER_BLOCK)  # fmt: skip
        sparse = view_bound is None
        if view_bound is None:  # sparse origins: evaluate them all at once
            block_of, view_bound, first_batch = np.zeros(n, dtype=np.int64), np.ones((1, 1), np.float32), n
        # float32 sums in a different order: a margin far above their rounding error
        view_bound = view_bound * np.float32(1.0 + BOUND_MARGIN) + np.float32(BOUND_MARGIN)
        block_bound = view_bound.max(axis=1)
        ordered = BoundOrder(block_bound, block_of)
        kept_gain = np.zeros(0, dtype=np.float32)
        kept_origin = kept_view = np.zeros(0, dtype=np.int64)
        bar = -1.0  # a gain must reach it to enter the ranking: the top_k-th best once there are top_k
        done, batch = 0, max(1, first_batch)
        while done < n:
            following, bounds = ordered.take(done, min(n, done + batch))
            if bounds[0] < bar:
                break
            stop = done + int(np.count_nonzero(bounds >= bar))
            # origins in grid order: the lanes and work-items of a work-group march from neighbouring cells
            chosen, view_sets = np.sort(following[: stop - done]), None
            if prune_views and bar >= 0.0 and not sparse:
                pattern, reach = reaching_views(view_bound, block_of[chosen], bar)
                by_pattern = np.argsort(pattern, kind="stable")  # work-groups of one view set
                chosen, view_sets = chosen[by_pattern], reach[pattern[by_pattern]]
            gains = self._views(code_buf, padded, origin_index[chosen], offset_buf, march, membership,
                                view_sets=view_sets)  # fmt: skip
            if allowed is not None:
                gains = np.where(allowed[chosen], gains, np.float32(0.0))
            rows, cols = np.nonzero((gains > 0.0) & (gains >= bar))
            kept_gain = np.concatenate([kept_gain, gains[rows, cols]])
            kept_origin = np.concatenate([kept_origin, chosen[rows]])
            kept_view = np.concatenate([kept_view, cols.astype(np.int64)])
            order = np.lexsort((kept_view, kept_origin, -kept_gain))[:top_k]
            kept_gain, kept_origin, kept_view = kept_gain[order], kept_origin[order], kept_view[order]
            if kept_gain.size == top_k:
                bar = float(kept_gain[-1])
            done, batch = stop, batch * 2
        return kept_origin, kept_view, kept_gain, done


def _march_args(march: RayMarch) -> list:
    """The kernels' arguments after the sample offsets: rays, samples per ray, ``nu``, the weight
    normaliser's inverse and itself, ``eps``, mode, minimum range and surface blend."""
    r, n_samples, dims = march.offsets.shape
    return [np.int32(r), np.int32(n_samples), np.int32(dims - 1), np.float32(1.0 / march.total_weight),
            np.float32(march.total_weight), np.float32(march.eps), np.int32(MODES[march.mode]),
            np.float32(march.min_range), np.float32(march.surface)]  # fmt: skip


def _border(march: RayMarch) -> float:
    """Padding code of the marched grid: occupied, or the border code (in (-2, -1): stops a ray,
    no return) for the original ``ig`` and for the ``"returns"`` model without walls."""
    if march.variant == "original" and march.mode == "ig":
        return ORIGINAL_BORDER_CODE
    options = march.options
    if options is not None and options.sensor is not None and not options.sensor.walls:
        return ORIGINAL_BORDER_CODE
    return -1.0


@functools.lru_cache(maxsize=1)
def get_ray_caster() -> OpenCLRayCaster:
    """The process-wide OpenCL ray caster (built on first use)."""
    return OpenCLRayCaster()


def forget_marched_grid() -> None:
    """:meth:`OpenCLRayCaster.forget_grid` of the process-wide caster, if one was built (benchmarks:
    each repeat on one grid marches it, as each plan of an exploration does)."""
    if get_ray_caster.cache_info().currsize:
        get_ray_caster().forget_grid()

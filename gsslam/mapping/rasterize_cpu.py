"""Compiled CPU compositor (exact per-pixel pair lists) and EWA projection, forward and hand-written
backward of each in C.

Why a plain C library loaded with :mod:`ctypes` (and not numba or a torch C++ extension): the kernel
needs nothing but raw float arrays, so it builds with any C compiler in about a second (a torch
extension needs the torch headers and takes about a minute on two cores), has no ABI tie to the
installed torch, and adds no dependency.

Where the library comes from (:mod:`gsslam.mapping.rasterize_build` holds the recipe):

1. installed: ``pip install`` builds ``_rasterize_cpu<EXT_SUFFIX>`` next to this file (setup.py);
   used when it was built from the current ``rasterize_cpu.c`` (it carries the source hash);
2. else built at first use with the system C compiler into a private cache folder
   (``$GSSLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/gsslam``, else ``~/.cache/gsslam``, else
   ``<tmp>/gsslam-<uid>``), keyed by the source hash; a folder or file another user could write is
   never loaded from;
3. else :func:`available` is False: ``render(backend="auto")`` uses the pure-torch reference (one
   warning) and ``backend="c"`` raises; both say :func:`unavailable_reason`.

The maths and the rules are those of :func:`gsslam.mapping.rasterize_reference.composite_reference`
and :func:`gsslam.mapping.projection.project_gaussians`; tests compare values and gradients of each pair.
"""

from __future__ import annotations

import ctypes
import importlib.machinery
import logging
import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch
from torch import Tensor

from gsslam.mapping import rasterize_build as build
from gsslam.mapping.projection import Projected

_log = logging.getLogger(__name__)

_VARIANTS = {torch.float32: "f32", torch.float64: "f64"}
_lib: ctypes.CDLL | None = None
_origin: str | None = None  # "installed" | "cache" | "built": where the loaded library came from
_failure: str | None = None  # why the kernel is unavailable (set once, then never retried)
_bands = 0  # row bands (threads) of the compositor's passes; 0: torch's thread count (compositor_threads)


@contextmanager
def compositor_threads(n: int) -> Iterator[None]:
    """Composite with ``n`` threads (row bands) inside the block, whatever torch's own thread count
    (``n <= 0``: torch's, the default). The passes are coarse (milliseconds each), unlike torch's
    per-operation thread pool, so they can use cores that torch's small operations would only wait on."""
    global _bands
    before, _bands = _bands, max(0, int(n))
    try:
        yield
    finally:
        _bands = before


def band_threads() -> int:
    """Threads the compositor's passes run on now (see :func:`compositor_threads`)."""
    return _bands if _bands > 0 else torch.get_num_threads()


def _compiler() -> str | None:
    for cand in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cand and shutil.which(cand):
            return cand
    return None


def _installed_library() -> Path | None:
    """The library ``pip install`` built next to this module (setup.py), if there is one."""
    stem = Path(__file__).with_name(build.EXT_NAME.rsplit(".", 1)[1])
    for suffix in importlib.machinery.EXTENSION_SUFFIXES:
        path = stem.with_name(stem.name + suffix)
        if path.is_file():
            return path
    return None


def _built_from(lib: ctypes.CDLL) -> str | None:
    try:
        fn = lib.gsslam_source_key_f32
    except AttributeError:
        return None
    fn.restype = ctypes.c_char_p
    fn.argtypes = []
    return fn().decode()


def _cached_library(key: str) -> tuple[Path, str]:
    """A library built from the current source in a private cache folder (built now if needed)."""
    problems = []
    for folder in build.cache_folders():
        try:
            build.private_folder(folder)
        except OSError as e:
            problems.append(f"{folder}: {e}")
            continue
        target = folder / f"rasterize_cpu_{key}.so"
        if os.path.lexists(target):
            problem = build.library_problem(target)
            if problem is None:
                return target, "cache"
            _log.warning("not loading %s (%s); building a fresh one", target, problem)
        cc = _compiler()
        if cc is None:
            raise RuntimeError("no C compiler found for the first-use build (set CC or install gcc)")
        try:
            build.compile_library(cc, target)
        except PermissionError as e:
            problems.append(f"{folder}: {e}")
            continue
        _log.info("built the CPU rasterizer kernel: %s", target)
        return target, "built"
    raise RuntimeError("no private folder to build the kernel in (" + "; ".join(problems) + ")")


def _load() -> ctypes.CDLL | None:
    global _lib, _origin, _failure
    if _lib is not None or _failure is not None:
        return _lib
    try:
        key = build.source_key() if build.SOURCE.is_file() else None
        installed = _installed_library()
        lib = ctypes.CDLL(str(installed)) if installed is not None else None
        if lib is not None and (key is None or _built_from(lib) == key):
            _origin = "installed"
        else:
            if key is None:
                raise RuntimeError(f"{build.SOURCE.name} is missing and no kernel is installed")
            if lib is not None:
                _log.info("%s was built from another %s; using a fresh build", installed, build.SOURCE.name)
            path, _origin = _cached_library(key)
            lib = ctypes.CDLL(str(path))
        _declare(lib)
        _lib = lib
    except (OSError, RuntimeError, subprocess.CalledProcessError) as e:
        detail = (getattr(e, "stderr", "") or "").strip()[:500]
        _failure = f"{e} {detail}".strip()
        _log.debug("compiled CPU rasterizer unavailable: %s", _failure)  # callers warn or raise
    return _lib


def unavailable_reason() -> str | None:
    """Why the compiled kernel cannot be used (None when it loaded); loads it on first call."""
    _load()
    return _failure


def origin() -> str | None:
    """Where the loaded kernel came from: "installed" (built by pip), "cache" or "built" (first use)."""
    _load()
    return _origin


def _declare(lib: ctypes.CDLL) -> None:
    p, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    for tag in _VARIANTS.values():
        getattr(lib, f"span_rows_{tag}").argtypes = [i64, i32, i32, p, p, p, p, p]
        getattr(lib, f"span_rows_{tag}").restype = i64
        getattr(lib, f"count_pairs_{tag}").argtypes = [i64, i32, i32, p, p, p, p, p, p, p, i32]
        getattr(lib, f"count_pairs_{tag}").restype = i64
        getattr(lib, f"fill_pairs_{tag}").argtypes = [i64, i32, i32, p, p, p, p, p, p, p, p, p, p, p, p, i32]
        getattr(lib, f"fill_pairs_{tag}").restype = None
        getattr(lib, f"composite_forward_{tag}").argtypes = [i32, i32, i32, p, p, p, p, p, p, p, i32]
        getattr(lib, f"composite_forward_{tag}").restype = None
        getattr(lib, f"composite_backward_{tag}").argtypes = [i32, i32, i32, i64] + [p] * 16 + [i32]
        getattr(lib, f"composite_backward_{tag}").restype = i32
        d = ctypes.c_double
        getattr(lib, f"project_forward_{tag}").argtypes = [i64] + [p] * 5 + [i32, i32, d, d] + [p] * 6
        getattr(lib, f"project_forward_{tag}").restype = None
        getattr(lib, f"project_backward_{tag}").argtypes = [i64] + [p] * 5 + [i32, i32, d, d] + [p] * 9
        getattr(lib, f"project_backward_{tag}").restype = None


def available(t: Tensor) -> bool:
    """True when the compiled kernel can composite tensors like ``t`` (CPU, float32/float64)."""
    return t.device.type == "cpu" and t.dtype in _VARIANTS and _load() is not None


def _ptr(t: Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


class _CompositeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, depths, radii, width, height, reuse):
        lib, tag = _lib, _VARIANTS[means2d.dtype]
        dt = means2d.dtype
        mu = means2d.detach().contiguous()
        con = conics.detach().to(dt).contiguous()
        op = opacities.detach().to(dt).contiguous()
        feat = features.detach().to(dt).contiguous()
        rad = radii.to(torch.int64).contiguous()
        n, f = feat.shape
        P = width * height
        threads = band_threads()
        order = torch.sort(depths.detach(), stable=True).indices.contiguous()
        counts = torch.empty(P, dtype=torch.int32)
        span_start = spans = None
        if reuse:  # every row's span found once (count pass), read by the fill pass
            span_start = torch.empty(n + 1, dtype=torch.int64)
            rows = getattr(lib, f"span_rows_{tag}")(
                n, width, height, _ptr(mu), _ptr(con), _ptr(op), _ptr(rad), _ptr(span_start)
            )
            spans = torch.empty(rows, 2, dtype=torch.int32)
        total = getattr(lib, f"count_pairs_{tag}")(
            n, width, height, _ptr(mu), _ptr(con), _ptr(op), _ptr(rad), _ptr(counts), _ptr(span_start),
            _ptr(spans), threads,
        )  # fmt: skip
        offsets = torch.zeros(P + 1, dtype=torch.int64)
        torch.cumsum(counts, 0, out=offsets[1:])
        cursor = torch.empty(P, dtype=torch.int64)
        pair_gid = torch.empty(total, dtype=torch.int32)
        pair_alpha = torch.empty(total, dtype=dt)
        need_grad = any(ctx.needs_input_grad[:4])  # no backward ahead (evaluation renders): nothing to keep
        pair_G = torch.empty(total, dtype=dt) if reuse and need_grad else None  # exp(-power) per pair
        getattr(lib, f"fill_pairs_{tag}")(
            n,
            width,
            height,
            _ptr(mu),
            _ptr(con),
            _ptr(op),
            _ptr(rad),
            _ptr(order),
            _ptr(offsets),
            _ptr(cursor),
            _ptr(pair_gid),
            _ptr(pair_alpha),
            _ptr(span_start),
            _ptr(spans),
            _ptr(pair_G),
            threads,
        )
        out_feat = torch.empty(P, f, dtype=dt)
        out_T = torch.empty(P, dtype=dt)
        n_used = torch.empty(P, dtype=torch.int32)
        getattr(lib, f"composite_forward_{tag}")(
            width,
            height,
            f,
            _ptr(offsets),
            _ptr(pair_gid),
            _ptr(pair_alpha),
            _ptr(feat),
            _ptr(out_feat),
            _ptr(out_T),
            _ptr(n_used),
            threads,
        )
        ctx.save_for_backward(mu, con, op, feat, offsets, pair_gid, pair_alpha, out_T, n_used)
        ctx.pair_G = pair_G
        ctx.size = (width, height)
        ctx.in_dtypes = (conics.dtype, opacities.dtype, features.dtype)
        return out_feat.view(height, width, f), (1.0 - out_T).view(height, width)

    @staticmethod
    def backward(ctx, g_feat_out, g_alpha_out):
        mu, con, op, feat, offsets, pair_gid, pair_alpha, out_T, n_used = ctx.saved_tensors
        width, height = ctx.size
        dt, tag = mu.dtype, _VARIANTS[mu.dtype]
        n, f = feat.shape
        if g_feat_out is None:
            g_feat_out = torch.zeros(height, width, f, dtype=dt)
        if g_alpha_out is None:
            g_alpha_out = torch.zeros(height, width, dtype=dt)
        g_feat_out = g_feat_out.to(dt).contiguous()
        g_alpha_out = g_alpha_out.to(dt).contiguous()
        g_mu, g_con = torch.zeros(n, 2, dtype=dt), torch.zeros(n, 3, dtype=dt)
        g_op, g_feat = torch.zeros(n, dtype=dt), torch.zeros(n, f, dtype=dt)
        status = getattr(_lib, f"composite_backward_{tag}")(
            width,
            height,
            f,
            n,
            _ptr(offsets),
            _ptr(pair_gid),
            _ptr(pair_alpha),
            _ptr(ctx.pair_G),
            _ptr(mu),
            _ptr(con),
            _ptr(op),
            _ptr(feat),
            _ptr(out_T),
            _ptr(n_used),
            _ptr(g_feat_out),
            _ptr(g_alpha_out),
            _ptr(g_mu),
            _ptr(g_con),
            _ptr(g_op),
            _ptr(g_feat),
            band_threads(),
        )
        if status != 0:
            raise MemoryError("the CPU rasterizer backward could not allocate its per-thread buffers")
        dc, do, df = ctx.in_dtypes
        return g_mu, g_con.to(dc), g_op.to(do), g_feat.to(df), None, None, None, None, None


def composite_cpu(
    means2d: Tensor,  # [N, 2] px
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, F], F <= 64
    depths: Tensor,  # [N] sort key
    radii: Tensor,  # [N] int, 0 = skip
    width: int,
    height: int,
    reuse: bool = True,
) -> tuple[Tensor, Tensor]:
    """Same contract as :func:`~gsslam.mapping.rasterize_reference.composite_reference`.

    ``reuse`` (default): the fill pass reads the row spans the count pass found, and the backward the
    ``exp(-power)`` of every pair the fill pass computed, instead of finding them again (session 8:
    the same values and gradients, bit for bit, in less time; tests/mapping/test_rasterize_fast.py).
    ``False`` runs the kernels as they were before, for that test and for speed comparisons.
    """
    if _load() is None:
        raise RuntimeError("the compiled CPU rasterizer is unavailable; check available() first")
    if features.shape[1] > 64:
        raise ValueError(f"at most 64 feature channels, got {features.shape[1]}")
    return _CompositeCPU.apply(
        means2d, conics, opacities, features, depths, radii, int(width), int(height), bool(reuse)
    )


class _ProjectCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, T, K, width, height, near, low_pass):
        tag, dt = _VARIANTS[means.dtype], means.dtype
        ins = [t.detach().to(dt).contiguous() for t in (means, quats, scales, T, K)]
        n = ins[0].shape[0]
        means2d, cov2d, conics = (torch.empty(n, k, dtype=dt) for k in (2, 4, 3))
        depths, normals = torch.empty(n, dtype=dt), torch.empty(n, 3, dtype=dt)
        radii = torch.empty(n, dtype=torch.int64)
        getattr(_lib, f"project_forward_{tag}")(
            n, *(_ptr(t) for t in ins), width, height, near, low_pass,
            *(_ptr(t) for t in (means2d, cov2d, conics, depths, radii, normals)),
        )  # fmt: skip
        ctx.save_for_backward(*ins)
        ctx.args = (width, height, near, low_pass)
        ctx.in_dtypes = (quats.dtype, scales.dtype, T.dtype)
        ctx.mark_non_differentiable(radii)
        return means2d, cov2d.view(n, 2, 2), conics, depths, radii, normals

    @staticmethod
    def backward(ctx, g_means2d, g_cov2d, g_conics, g_depths, _g_radii, g_normals):
        ins = ctx.saved_tensors
        dt, tag = ins[0].dtype, _VARIANTS[ins[0].dtype]
        n = ins[0].shape[0]
        shapes = ((n, 2), (n, 2, 2), (n, 3), (n,), (n, 3))
        grads = [
            torch.zeros(sh, dtype=dt) if g is None else g.to(dt).contiguous()
            for g, sh in zip((g_means2d, g_cov2d, g_conics, g_depths, g_normals), shapes)
        ]
        g_means, g_quats, g_scales = (torch.empty(n, k, dtype=dt) for k in (3, 4, 3))
        g_T = torch.zeros(4, 4, dtype=dt)
        getattr(_lib, f"project_backward_{tag}")(
            n, *(_ptr(t) for t in ins), *ctx.args, *(_ptr(g) for g in grads),
            _ptr(g_means), _ptr(g_quats), _ptr(g_scales), _ptr(g_T),
        )  # fmt: skip
        dq, ds, dT = ctx.in_dtypes
        return g_means, g_quats.to(dq), g_scales.to(ds), g_T.to(dT), None, None, None, None, None


def project_cpu(
    means: Tensor,  # [N, 3] world
    quats: Tensor,  # [N, 4] (w, x, y, z)
    scales: Tensor,  # [N, 3] linear
    T_cam_world: Tensor,  # [4, 4]
    K: Tensor,  # [3, 3] (no gradient)
    width: int,
    height: int,
    near: float = 0.01,
    low_pass: float = 0.3,
) -> Projected:
    """:func:`~gsslam.mapping.projection.project_gaussians` in C (one pass forward, one backward).

    The same maths, values equal to rounding and gradients w.r.t. ``means``, ``quats``, ``scales`` and
    ``T_cam_world`` (tests/mapping/test_project_cpu.py); instead of ~100 torch operations forward and
    ~200 backward. ``K`` gets no gradient. Needs the kernel (:func:`available` of ``means``).
    """
    if _load() is None:
        raise RuntimeError("the compiled CPU rasterizer is unavailable; check available() first")
    means2d, cov2d, conics, depths, radii, normals = _ProjectCPU.apply(
        means, quats, scales, T_cam_world, K.detach(), int(width), int(height), float(near), float(low_pass)
    )
    return Projected(means2d=means2d, cov2d=cov2d, conics=conics, depths=depths, radii=radii, normals=normals)

"""Compiled CPU compositor: exact per-pixel pair lists, forward and hand-written backward in C.

Why a plain C library loaded with :mod:`ctypes` (and not numba or a torch C++ extension): the kernel
needs nothing but raw float arrays, so it builds with the system C compiler in about a second
(a torch extension needs the torch headers and takes about a minute on two cores), has no ABI tie to
the installed torch, and adds no dependency. It is built at first use from ``rasterize_cpu.c`` into
a cache folder (``$GSSLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/gsslam``, else ``~/.cache/gsslam``),
keyed by a hash of the source and flags. Without a working compiler, :func:`available` is False and
:func:`gsslam.mapping.rasterize.render` falls back to the pure-torch reference (with one warning).

The maths and the rules are those of :func:`gsslam.mapping.rasterize_reference.composite_reference`;
tests compare values and gradients of the two.
"""

from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import torch
from torch import Tensor

_log = logging.getLogger(__name__)

_SOURCE = Path(__file__).with_name("rasterize_cpu.c")
_FLAGS = ["-O3", "-fPIC", "-std=gnu99", "-ffp-contract=off", "-pthread"]
_VARIANTS = {torch.float32: ("f32", "float", "expf"), torch.float64: ("f64", "double", "exp")}
_lib: ctypes.CDLL | None = None
_load_failed = False


def _cache_dir() -> Path:
    if os.environ.get("GSSLAM_CACHE_DIR"):
        return Path(os.environ["GSSLAM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "gsslam"


def _compiler() -> str | None:
    for cand in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if cand and shutil.which(cand):
            return cand
    return None


def _build(cc: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        objs = []
        for tag, real, exp in _VARIANTS.values():
            obj = Path(tmp) / f"{tag}.o"
            defs = [f"-DREAL={real}", f"-DTAG={tag}", f"-DEXP={exp}"]
            subprocess.run(
                [cc, *_FLAGS, *defs, "-c", str(_SOURCE), "-o", str(obj)],
                check=True,
                capture_output=True,
                text=True,
            )
            objs.append(str(obj))
        out = Path(tmp) / target.name
        subprocess.run(
            [cc, "-shared", "-pthread", *objs, "-o", str(out), "-lm"],
            check=True,
            capture_output=True,
            text=True,
        )
        os.replace(out, target)  # atomic: concurrent builders never see a half-written library


def _load() -> ctypes.CDLL | None:
    global _lib, _load_failed
    if _lib is not None or _load_failed:
        return _lib
    try:
        if not _SOURCE.is_file():
            raise FileNotFoundError(f"{_SOURCE} is missing from the installation")
        cc = _compiler()
        key = hashlib.sha256(_SOURCE.read_bytes() + " ".join(_FLAGS).encode()).hexdigest()[:16]
        target = _cache_dir() / f"rasterize_cpu_{key}.so"
        if not target.is_file():
            if cc is None:
                raise RuntimeError("no C compiler found (set CC or install gcc)")
            try:
                _build(cc, target)
            except PermissionError:
                target = Path(tempfile.gettempdir()) / "gsslam" / target.name
                if not target.is_file():
                    _build(cc, target)
            _log.info("built the CPU rasterizer kernel: %s", target)
        lib = ctypes.CDLL(str(target))
        _declare(lib)
        _lib = lib
    except (OSError, RuntimeError, subprocess.CalledProcessError) as e:
        detail = getattr(e, "stderr", "") or ""
        _log.warning(
            "compiled CPU rasterizer unavailable (%s %s); using the slower pure-torch reference",
            e,
            detail.strip()[:500],
        )
        _load_failed = True
    return _lib


def _declare(lib: ctypes.CDLL) -> None:
    p, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    for tag, _, _ in _VARIANTS.values():
        getattr(lib, f"count_pairs_{tag}").argtypes = [i64, i32, i32, p, p, p, p, p, i32]
        getattr(lib, f"count_pairs_{tag}").restype = i64
        getattr(lib, f"fill_pairs_{tag}").argtypes = [i64, i32, i32, p, p, p, p, p, p, p, p, p, i32]
        getattr(lib, f"fill_pairs_{tag}").restype = None
        getattr(lib, f"composite_forward_{tag}").argtypes = [i32, i32, i32, p, p, p, p, p, p, p, i32]
        getattr(lib, f"composite_forward_{tag}").restype = None
        getattr(lib, f"composite_backward_{tag}").argtypes = [i32, i32, i32, i64] + [p] * 15 + [i32]
        getattr(lib, f"composite_backward_{tag}").restype = i32


def available(t: Tensor) -> bool:
    """True when the compiled kernel can composite tensors like ``t`` (CPU, float32/float64)."""
    return t.device.type == "cpu" and t.dtype in _VARIANTS and _load() is not None


def _ptr(t: Tensor) -> int:
    return t.data_ptr()


class _CompositeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, depths, radii, width, height):
        lib, tag = _lib, _VARIANTS[means2d.dtype][0]
        dt = means2d.dtype
        mu = means2d.detach().contiguous()
        con = conics.detach().to(dt).contiguous()
        op = opacities.detach().to(dt).contiguous()
        feat = features.detach().to(dt).contiguous()
        rad = radii.to(torch.int64).contiguous()
        n, f = feat.shape
        P = width * height
        threads = torch.get_num_threads()
        order = torch.sort(depths.detach(), stable=True).indices.contiguous()
        counts = torch.empty(P, dtype=torch.int32)
        total = getattr(lib, f"count_pairs_{tag}")(
            n, width, height, _ptr(mu), _ptr(con), _ptr(op), _ptr(rad), _ptr(counts), threads
        )
        offsets = torch.zeros(P + 1, dtype=torch.int64)
        torch.cumsum(counts, 0, out=offsets[1:])
        cursor = torch.empty(P, dtype=torch.int64)
        pair_gid = torch.empty(total, dtype=torch.int32)
        pair_alpha = torch.empty(total, dtype=dt)
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
        ctx.size = (width, height)
        ctx.in_dtypes = (conics.dtype, opacities.dtype, features.dtype)
        return out_feat.view(height, width, f), (1.0 - out_T).view(height, width)

    @staticmethod
    def backward(ctx, g_feat_out, g_alpha_out):
        mu, con, op, feat, offsets, pair_gid, pair_alpha, out_T, n_used = ctx.saved_tensors
        width, height = ctx.size
        dt, tag = mu.dtype, _VARIANTS[mu.dtype][0]
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
            torch.get_num_threads(),
        )
        if status != 0:
            raise MemoryError("the CPU rasterizer backward could not allocate its per-thread buffers")
        dc, do, df = ctx.in_dtypes
        return g_mu, g_con.to(dc), g_op.to(do), g_feat.to(df), None, None, None, None


def composite_cpu(
    means2d: Tensor,  # [N, 2] px
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    features: Tensor,  # [N, F], F <= 64
    depths: Tensor,  # [N] sort key
    radii: Tensor,  # [N] int, 0 = skip
    width: int,
    height: int,
) -> tuple[Tensor, Tensor]:
    """Same contract as :func:`~gsslam.mapping.rasterize_reference.composite_reference`."""
    if _load() is None:
        raise RuntimeError("the compiled CPU rasterizer is unavailable; check available() first")
    if features.shape[1] > 64:
        raise ValueError(f"at most 64 feature channels, got {features.shape[1]}")
    return _CompositeCPU.apply(means2d, conics, opacities, features, depths, radii, int(width), int(height))

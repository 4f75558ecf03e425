"""Portable kernel paths: the same seed gives the same bytes on every x86-64 CPU with AVX2
(issue 25; docs/engine.md, "Kernel pinning").

torch, MKL, oneDNN, OpenBLAS and numpy each pick their float kernels per CPU: AVX-512 or AMX
on one host, AVX2 on another, a vendor-specific MKL branch, oneDNN blockings sized by the
cache.  The last bits differ, training amplifies them, and a committed baseline then holds only
on the CPU that made it.  *Pinned* (the default at every scale) fixes every one of those
choices to a level every supported x86-64 CPU has:

- ``ATEN_CPU_CAPABILITY=avx2``: ATen's vectorised kernels at AVX2 (never AVX-512);
- ``MKL_CBWR=COMPATIBLE``: MKL's conditional numerical reproducibility on its vendor-neutral
  branch.  MKL's ``AVX2`` branch is reproducible across *Intel* CPUs only: on any other vendor
  MKL silently uses ``AUTO`` (measured here: ``MKL_CBWR=AVX2`` reads back as AUTO on an AMD
  EPYC), so COMPATIBLE is the one branch that gives Intel and AMD the same bits;
  ``MKL_DYNAMIC``/``OMP_DYNAMIC=FALSE`` keep the thread count fixed;
- oneDNN off (``torch.backends.mkldnn.enabled = False``, and ``ONEDNN_MAX_CPU_ISA=AVX2`` for
  anything that still reaches it): oneDNN promises equal results only "on a given platform",
  and its LSTM gave other bits under an emulated Intel CPU at the same ISA cap; NNPACK off too
  (``torch.backends.nnpack.set_flags(False)``: it takes convolutions of batch >= 16 with its
  own CPU detection and cache-sized blocking); convolutions and RNNs then run ATen's own
  kernels over MKL's GEMM;
- ``OPENBLAS_CORETYPE=Haswell``: numpy's and scipy's OpenBLAS use their AVX2 kernels (an
  AVX-512 host would pick SkylakeX or newer), ``OPENBLAS_NUM_THREADS=1`` on one thread;
- torch's CPU matrix products (``mm``, ``addmm``, ``bmm``, ``baddbmm``: every linear layer,
  attention product, RNN gate and their gradients) computed by that OpenBLAS
  (:mod:`repro.gemm`, pin version 2, issue 31): the same AVX2/FMA kernels on every such CPU,
  2.7-2.9x faster than MKL's COMPATIBLE (SSE2) GEMM, which before computed them;
- ``NPY_DISABLE_CPU_FEATURES``: numpy's AVX-512 dispatch targets off (its ufunc loops and
  float reductions use other code, hence other bits, on AVX-512);
- ``torch.use_deterministic_algorithms(True)``; thread counts are fixed per job by the scale
  profile (``threads``, already in every key).

Some torch ops give host-dependent bits even so: torch sends ``sqrt`` and ``acos`` (float32 and
float64) to MKL's vector maths, whose results differed under an emulated Intel CPU with
everything above pinned, and with them ``pow(x, 0.5)``, ``cdist`` and the non-fused
Adam/AdamW/RMSprop updates.  So the library computes a square root with :func:`sqrt`
(``1 / rsqrt(x)``: ATen's ``rsqrt`` is the IEEE square root and a division, the same bits on
every CPU), ranks nearest neighbours by squared distances, and builds its optimisers with
:func:`adam` / :func:`adamw` (torch's fused CPU kernels, whose square root is the IEEE
instruction).  ``benchmarks/bench_kernel_paths.py`` holds the evidence.

The environment is set by :func:`pin_environment`, which ``import repro`` calls before any
numeric library is imported (so the CLI, its pool workers, which inherit the environment, and
Ray workers, which get :func:`worker_env`, all compute pinned).  ``REPRO_FAST_KERNELS=1`` (the
CLI's ``--fast-kernels``) lifts it: the process keeps its host's fastest paths, its job keys
name the host's paths instead of the pin (so a shared store never mixes the two), its run
record says so, and ``repro verify`` refuses to compare it with pinned baselines.  Whether
the pin is really in force is *measured* (:func:`state`) before every job computes
(:func:`check`): a process that imported torch before ``repro`` cannot be pinned after the fact
and is refused with one line.
"""

from __future__ import annotations

import os
from typing import Any

#: bump when the pinned settings change (part of every job key)
PIN_VERSION = 2  # 2: matrix products on numpy's OpenBLAS (repro/gemm.py), one BLAS thread
PIN_NAME = "x86-64-avx2-portable"
FAST_ENV = "REPRO_FAST_KERNELS"

#: what :func:`pin_environment` sets (overriding values already in the environment)
PINNED_ENV: dict[str, str] = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "COMPATIBLE",
    "MKL_DYNAMIC": "FALSE",
    "OMP_DYNAMIC": "FALSE",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "DNNL_MAX_CPU_ISA": "AVX2",
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENBLAS_NUM_THREADS": "1",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
}

#: Environment variables that choose kernel paths (the pin's, and the two it clears or that
#: widen MKL's): under fast kernels their ambient values enter the job key (:func:`key`)
PATH_ENV = frozenset(PINNED_ENV) | {"NPY_ENABLE_CPU_FEATURES", "MKL_ENABLE_INSTRUCTIONS"}

#: MKL's ``mkl_cbwr_get(MKL_CBWR_BRANCH)`` codes (mkl_cbwr.h)
_MKL_BRANCHES = {1: "OFF", 2: "AUTO", 3: "COMPATIBLE", 4: "SSE2", 6: "SSSE3", 7: "SSE4_1",
                 8: "SSE4_2", 9: "AVX", 10: "AVX2", 11: "AVX512_MIC", 12: "AVX512",
                 13: "AVX512_MIC_E1", 14: "AVX512_E1"}


def fast_requested() -> bool:
    """True when this process was asked to keep the host's fastest kernels."""
    return os.environ.get(FAST_ENV, "").strip().lower() in ("1", "true", "yes", "on")


def pin_environment() -> bool:
    """Set :data:`PINNED_ENV` in ``os.environ`` unless :func:`fast_requested`; returns whether
    it pinned.  Effective only before torch / numpy are imported (they read it at load);
    :func:`check` tells whether it took."""
    if fast_requested():
        return False
    os.environ.update(PINNED_ENV)
    os.environ.pop("NPY_ENABLE_CPU_FEATURES", None)  # numpy refuses it beside the DISABLE list
    return True


def worker_env() -> dict[str, str]:
    """The environment a remote worker (Ray) needs to compute as this process does."""
    if fast_requested():
        return {FAST_ENV: "1"}
    return {**PINNED_ENV, FAST_ENV: "0"}


def apply_runtime() -> None:
    """The torch settings of the pin (process-wide; a no-op under fast kernels)."""
    if fast_requested():
        return
    import torch

    torch.backends.mkldnn.enabled = False
    torch.backends.nnpack.set_flags(False)
    torch.use_deterministic_algorithms(True)
    from repro import gemm

    gemm.install()  # torch's matrix products on the pinned OpenBLAS (repro/gemm.py)


def _mkl_branch() -> str | None:
    """MKL's CNR branch in force in this process (read from torch's statically linked MKL;
    None where the symbol is not exported)."""
    import ctypes

    import torch

    lib = os.path.join(os.path.dirname(torch.__file__), "lib", "libtorch_cpu.so")
    try:
        fn = ctypes.CDLL(lib).mkl_serv_cbwr_get
    except (OSError, AttributeError):
        return None
    fn.restype = ctypes.c_int
    code = int(fn(1))
    return _MKL_BRANCHES.get(code, str(code))


def state() -> dict[str, Any]:
    """The kernel paths in force in this process, as measured (imports torch and numpy)."""
    import numpy as np
    import torch

    from numpy._core._multiarray_umath import __cpu_features__ as npf

    try:
        from threadpoolctl import threadpool_info

        pools = [i for i in threadpool_info() if i.get("internal_api") == "openblas"]
        blas = sorted({i.get("architecture") or "?" for i in pools})
        blas_threads = sorted({int(i.get("num_threads") or 0) for i in pools})
    except Exception:  # pragma: no cover - threadpoolctl is a dependency
        blas, blas_threads = [], []
    from repro import gemm

    return {
        "aten": torch.backends.cpu.get_cpu_capability(),
        "mkl_cbwr": _mkl_branch(),
        "onednn": bool(torch.backends.mkldnn.enabled),
        "nnpack": bool(torch._nnpack_available() and torch._C._get_nnpack_enabled()),
        "deterministic_algorithms": bool(torch.are_deterministic_algorithms_enabled()),
        "openblas": blas,
        "openblas_threads": blas_threads,
        "gemm": gemm.NAME if gemm.installed() else "torch",
        "numpy_avx512": bool(npf.get("X86_V4") or npf.get("AVX512_SKX")),
        "numpy": np.__version__, "torch": torch.__version__.split("+")[0],
    }


def pinned_in_force(st: dict[str, Any]) -> list[str]:
    """What in the measured state ``st`` differs from the pin (empty: pinned)."""
    bad = []
    if str(st.get("aten", "")).upper() != "AVX2":
        bad.append(f"ATen capability {st.get('aten')} (want AVX2)")
    if st.get("mkl_cbwr") not in (None, "COMPATIBLE"):
        bad.append(f"MKL branch {st.get('mkl_cbwr')} (want COMPATIBLE)")
    if st.get("onednn"):
        bad.append("oneDNN enabled")
    if st.get("nnpack"):
        bad.append("NNPACK enabled")
    if not st.get("deterministic_algorithms"):
        bad.append("deterministic algorithms off")
    if any(b not in ("Haswell", "?") for b in st.get("openblas", [])):
        bad.append(f"OpenBLAS core {','.join(st['openblas'])} (want Haswell)")
    if any(n != 1 for n in st.get("openblas_threads", [])):
        bad.append(f"OpenBLAS threads {st['openblas_threads']} (want 1)")
    if "gemm" in st and st["gemm"] == "torch":
        bad.append("matrix products on torch's own kernels (want repro.gemm)")
    if st.get("numpy_avx512"):
        bad.append("numpy AVX-512 dispatch on")
    return bad


def check() -> dict[str, Any]:
    """Apply the runtime settings and refuse (ConfigError) a process that was asked to compute
    pinned but is not (torch or numpy imported before ``repro`` pinned the environment).
    Returns the measured :func:`state`."""
    apply_runtime()
    st = state()
    if not fast_requested():
        bad = pinned_in_force(st)
        if bad and host_paths()["isa"] not in ("AVX2", "AVX512", "AMX"):
            from repro.errors import ConfigError

            raise ConfigError(f"kernel pinning needs an x86-64 CPU with AVX2; this one is "
                              f"{host_paths()['isa']} ({'; '.join(bad)}): run with "
                              "--fast-kernels (REPRO_FAST_KERNELS=1) and compare with "
                              "verify --tolerance")
        if bad:
            from repro.errors import ConfigError

            raise ConfigError("kernel pinning is not in force in this process ("
                              + "; ".join(bad) + "): import repro before torch/numpy, or "
                              "run with --fast-kernels (REPRO_FAST_KERNELS=1) and compare "
                              "without the pinned baselines")
    return st


def cpu_description() -> tuple[str | None, str | None, set[str]]:
    """``(vendor, model name, flags)`` of the first CPU in /proc/cpuinfo (None, None, empty
    where there is none)."""
    vendor, model, flags = None, None, set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                name, _, value = line.partition(":")
                name = name.strip()
                if name == "vendor_id" and vendor is None:
                    vendor = value.strip()
                elif name == "model name" and model is None:
                    model = value.strip()
                elif name == "flags":
                    flags = set(value.split())
                    break
    except OSError:
        pass
    return vendor, model, flags


def host_paths() -> dict[str, Any]:
    """What this CPU would compute with unpinned: vendor, model and the widest vector ISA
    (no numeric library imported)."""
    vendor, model, flags = cpu_description()
    isa = ("AMX" if "amx_tile" in flags else "AVX512" if "avx512f" in flags
           else "AVX2" if "avx2" in flags else "below AVX2" if flags else "unknown")
    return {"vendor": vendor, "model": model, "isa": isa}


def key() -> dict[str, Any]:
    """The kernel part of every job key: the pin (any AVX2 host computes the same bytes), or,
    under fast kernels, the host's own paths (bytes of one kind of CPU)."""
    if fast_requested():
        h = host_paths()
        out = {"mode": "fast", "vendor": h["vendor"], "model": h["model"], "isa": h["isa"]}
        # the environment still chooses paths on one host (ATEN_CPU_CAPABILITY=default changes
        # 40 of the op battery's 50 results, MKL_CBWR=COMPATIBLE 7): a fast key names what was
        # set, so one store never hands such bytes to a run with other settings
        ambient = {k: os.environ[k] for k in sorted(PATH_ENV) if k in os.environ}
        if ambient:
            out["ambient"] = ambient
        return out
    return {"mode": "pinned", "pin": PIN_NAME, "version": PIN_VERSION}


def record() -> dict[str, Any]:
    """What a run record and a baseline say about kernels: the mode, the host, the pin's
    settings and, once torch is loaded in this process (a table run checks the pin before it
    records), the paths measured in force (:func:`state`)."""
    import sys

    mode = "fast" if fast_requested() else "pinned"
    out: dict[str, Any] = {"mode": mode, "host": host_paths()}
    if "torch" in sys.modules and "numpy" in sys.modules:
        out["in_force"] = state()
    if mode == "pinned":
        out.update(pin=PIN_NAME, version=PIN_VERSION, settings=dict(PINNED_ENV),
                   runtime={"onednn": False, "nnpack": False,
                            "deterministic_algorithms": True, "gemm": "numpy-openblas"})
    return out


def describe(rec: dict[str, Any] | None) -> str:
    """One line for a footer or ``verify``: ``pinned x86-64-avx2-portable v1 on AMD EPYC
    (AuthenticAMD, AVX2)``; records older than the pin read "not recorded (before pinning)"."""
    if not rec:
        return "not recorded (made before kernel pinning)"
    h = rec.get("host") or {}
    where = f"{h.get('model') or '?'} ({h.get('vendor') or '?'}, {h.get('isa') or '?'})"
    if rec.get("mode") == "pinned":
        if int(rec.get("version") or 0) >= 2:
            return (f"pinned {rec.get('pin')} v{rec.get('version')} (ATen AVX2, matrix products "
                    "on OpenBLAS Haswell, MKL COMPATIBLE, oneDNN and NNPACK off, numpy without "
                    f"AVX-512) on {where}")
        return (f"pinned {rec.get('pin')} v{rec.get('version')} (ATen AVX2, MKL COMPATIBLE, "
                f"oneDNN and NNPACK off, OpenBLAS Haswell, numpy without AVX-512) on {where}")
    return f"fast (unpinned: the host's own kernel paths) on {where}"


# ---------------------------------------------------------------------------------------------
# the two torch ops the environment cannot pin

def sqrt(x):
    """``sqrt(x)`` (x >= 0) with the same bits on every CPU: ``1 / rsqrt(x)``, where ATen's
    ``rsqrt`` is the IEEE square root followed by a division (within one ulp of the correctly
    rounded root; exact 0 at 0).  torch's own ``sqrt`` goes to MKL's vector maths, whose bits
    depend on the host (module docstring)."""
    import torch

    return torch.reciprocal(torch.rsqrt(x))


def adam(params, **kw):
    """``torch.optim.Adam`` on torch's fused CPU kernel (host-independent square root)."""
    import torch

    params = list(params)
    return torch.optim.Adam(params, fused=_fused_ok_all(params), **kw)


def adamw(params, **kw):
    """``torch.optim.AdamW`` on torch's fused CPU kernel (host-independent square root)."""
    import torch

    params = list(params)
    return torch.optim.AdamW(params, fused=_fused_ok_all(params), **kw)


def _fused_ok_all(params) -> bool:
    """Fused where every tensor allows it (a CUDA model keeps torch's CUDA choice)."""
    if params and isinstance(params[0], dict):  # parameter groups: keep each group's list
        for g in params:
            g["params"] = list(g["params"])
        tensors = [p for g in params for p in g["params"]]
    else:
        tensors = params
    return all(p.device.type == "cpu" and p.dtype.is_floating_point for p in tensors)


"""Where a compiled Euler -> quaternion kernel spends its time: rows in memory, not arithmetic.

A developer's model (not installed, x86-64 with AVX2 and FMA, needs ``g++``). The compiled Euler
ZYX -> quat kernel is one inductor loop over 8 rows at a time: it reads each angle column with 8
scalar loads into a buffer (rows of 3 floats, stride 3) and writes each quaternion component with 8
scalar stores out of one (rows of 4). This writes the same arithmetic (the shipped half-angle
cosine and sinc polynomials, ``torchquat._polynomials``, and the ZYX product with ``w >= 0``) in
C++ with AVX2 intrinsics five ways, one thread, and times them on the same 1e6 rows beside the
bench's memory floor:

- ``inductor``: the columns gathered and scattered as inductor 2.13 writes them;
- ``shuffled loads``: three vector loads of 8 rows, each column picked by two shuffles;
- ``transposed stores``: the four components transposed in registers (unpack, shuffle,
  permute) and written as four vector stores of 8 whole rows;
- ``both``: shuffled loads and transposed stores;
- ``planes``: the angles and the components in contiguous planes (no layout at all).

Each variant's output is checked against ``torchquat.euler_to_quat`` in float64. Run::

    GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=68719476736 \\
        python tools/layout_model.py [--n 1000000] [--rounds 40] [--min-run-time 0.05] [--compiled]

``--compiled`` also times torchquat's own compiled kernel (``use_compiled_kernels``) in the same
process. ``docs/bench_profile.md`` ("Rows in memory: a model in C++ (session 27)") has the
figures on the EPYC this project's numbers come from.
"""

import argparse
import ctypes
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile

import torch

# (the first four are euler_rows's variants 0-3, in this order; "planes" is euler_planes)
VARIANTS = ("inductor", "shuffled loads", "transposed stores", "both", "planes")

_SOURCE = r"""
#include <immintrin.h>
#include <cstring>

static const float HALF_COS[] = {HALF_COS_COEFFICIENTS};
static const float HALF_SINC[] = {HALF_SINC_COEFFICIENTS};
static const int DEGREE = sizeof(HALF_COS) / sizeof(float);

// cos(h) and sin(h) of half angles h = a / 2 (|a| <= pi): 1 + h^2 P(h^2) and h (1 + h^2 Q(h^2))
static inline void half_cos_sin(__m256 angle, __m256 &c, __m256 &s) {
    __m256 h = _mm256_mul_ps(angle, _mm256_set1_ps(0.5f)), h2 = _mm256_mul_ps(h, h);
    __m256 p = _mm256_set1_ps(HALF_COS[DEGREE - 1]), q = _mm256_set1_ps(HALF_SINC[DEGREE - 1]);
    for (int k = DEGREE - 2; k >= 0; k--) {
        p = _mm256_fmadd_ps(p, h2, _mm256_set1_ps(HALF_COS[k]));
        q = _mm256_fmadd_ps(q, h2, _mm256_set1_ps(HALF_SINC[k]));
    }
    c = _mm256_fmadd_ps(p, h2, _mm256_set1_ps(1.0f));
    s = _mm256_mul_ps(h, _mm256_fmadd_ps(q, h2, _mm256_set1_ps(1.0f)));
}

// intrinsic ZYX: q = qz(a0) qy(a1) qx(a2), w >= 0
static inline void euler_zyx_to_quat(__m256 a0, __m256 a1, __m256 a2, __m256 &w, __m256 &x, __m256 &y, __m256 &z) {
    __m256 c0, s0, c1, s1, c2, s2;
    half_cos_sin(a0, c0, s0); half_cos_sin(a1, c1, s1); half_cos_sin(a2, c2, s2);
    __m256 cc = _mm256_mul_ps(c0, c1), ss = _mm256_mul_ps(s0, s1), cs = _mm256_mul_ps(c0, s1), sc = _mm256_mul_ps(s0, c1);
    w = _mm256_fmadd_ps(cc, c2, _mm256_mul_ps(ss, s2));
    x = _mm256_fmsub_ps(cc, s2, _mm256_mul_ps(ss, c2));
    y = _mm256_fmadd_ps(cs, c2, _mm256_mul_ps(sc, s2));
    z = _mm256_fmsub_ps(sc, c2, _mm256_mul_ps(cs, s2));
    __m256 sign = _mm256_and_ps(w, _mm256_set1_ps(-0.0f));
    w = _mm256_xor_ps(w, sign); x = _mm256_xor_ps(x, sign); y = _mm256_xor_ps(y, sign); z = _mm256_xor_ps(z, sign);
}

// column j of 8 rows of 3: 8 scalar loads into a buffer, then one vector load (inductor's way)
static inline __m256 gathered(const float *rows, int j) {
    alignas(32) float buffer[8];
    for (int i = 0; i < 8; i++) buffer[i] = rows[3 * i + j];
    return _mm256_load_ps(buffer);
}

// column j of 8 rows of 3 from three vector loads, by two shuffles
typedef float v8 __attribute__((vector_size(32)));
typedef int v8i __attribute__((vector_size(32)));
template <int J> static inline __m256 shuffled(const float *rows) {
    v8 v0, v1, v2;
    std::memcpy(&v0, rows, 32); std::memcpy(&v1, rows + 8, 32); std::memcpy(&v2, rows + 16, 32);
    constexpr int e[8] = {J, J + 3, J + 6, J + 9, J + 12, J + 15, J + 18, J + 21};
    v8 t = __builtin_shuffle(v0, v1, (v8i){e[0] < 16 ? e[0] : 0, e[1] < 16 ? e[1] : 0, e[2] < 16 ? e[2] : 0, e[3] < 16 ? e[3] : 0,
                                           e[4] < 16 ? e[4] : 0, e[5] < 16 ? e[5] : 0, e[6] < 16 ? e[6] : 0, e[7] < 16 ? e[7] : 0});
    return (__m256)__builtin_shuffle(t, v2, (v8i){e[0] < 16 ? 0 : e[0] - 8, e[1] < 16 ? 1 : e[1] - 8, e[2] < 16 ? 2 : e[2] - 8,
                                                  e[3] < 16 ? 3 : e[3] - 8, e[4] < 16 ? 4 : e[4] - 8, e[5] < 16 ? 5 : e[5] - 8,
                                                  e[6] < 16 ? 6 : e[6] - 8, e[7] < 16 ? 7 : e[7] - 8});
}

// component k of 8 rows of 4: one vector store into a buffer, then 8 scalar stores (inductor's way)
static inline void scattered(float *rows, int k, __m256 value) {
    alignas(32) float buffer[8];
    _mm256_store_ps(buffer, value);
    for (int i = 0; i < 8; i++) rows[4 * i + k] = buffer[i];
}

// four components of 8 rows, transposed in registers: four vector stores of two rows each
static inline void transposed(float *rows, __m256 w, __m256 x, __m256 y, __m256 z) {
    __m256 t0 = _mm256_unpacklo_ps(w, x), t1 = _mm256_unpackhi_ps(w, x);
    __m256 t2 = _mm256_unpacklo_ps(y, z), t3 = _mm256_unpackhi_ps(y, z);
    __m256 r0 = _mm256_shuffle_ps(t0, t2, 0x44), r1 = _mm256_shuffle_ps(t0, t2, 0xEE);
    __m256 r2 = _mm256_shuffle_ps(t1, t3, 0x44), r3 = _mm256_shuffle_ps(t1, t3, 0xEE);
    _mm256_storeu_ps(rows, _mm256_permute2f128_ps(r0, r1, 0x20));
    _mm256_storeu_ps(rows + 8, _mm256_permute2f128_ps(r2, r3, 0x20));
    _mm256_storeu_ps(rows + 16, _mm256_permute2f128_ps(r0, r1, 0x31));
    _mm256_storeu_ps(rows + 24, _mm256_permute2f128_ps(r2, r3, 0x31));
}

template <bool SHUFFLED, bool TRANSPOSED> static void rows_kernel(const float *angles, float *quats, long n) {
    for (long i = 0; i < n; i += 8) {
        const float *in = angles + 3 * i;
        float *out = quats + 4 * i;
        __m256 a0 = SHUFFLED ? shuffled<0>(in) : gathered(in, 0);
        __m256 a1 = SHUFFLED ? shuffled<1>(in) : gathered(in, 1);
        __m256 a2 = SHUFFLED ? shuffled<2>(in) : gathered(in, 2);
        __m256 w, x, y, z;
        euler_zyx_to_quat(a0, a1, a2, w, x, y, z);
        if (TRANSPOSED) {
            transposed(out, w, x, y, z);
        } else {
            scattered(out, 0, w); scattered(out, 1, x); scattered(out, 2, y); scattered(out, 3, z);
        }
    }
}

extern "C" void euler_rows(int variant, const float *angles, float *quats, long n) {
    switch (variant) {
        case 0: rows_kernel<false, false>(angles, quats, n); break;
        case 1: rows_kernel<true, false>(angles, quats, n); break;
        case 2: rows_kernel<false, true>(angles, quats, n); break;
        case 3: rows_kernel<true, true>(angles, quats, n); break;
    }
}

// planes: (3, n) angles in, (4, n) components out
extern "C" void euler_planes(const float *angles, float *quats, long n) {
    for (long i = 0; i < n; i += 8) {
        __m256 w, x, y, z;
        euler_zyx_to_quat(_mm256_loadu_ps(angles + i), _mm256_loadu_ps(angles + n + i), _mm256_loadu_ps(angles + 2 * n + i), w, x, y, z);
        _mm256_storeu_ps(quats + i, w); _mm256_storeu_ps(quats + n + i, x);
        _mm256_storeu_ps(quats + 2 * n + i, y); _mm256_storeu_ps(quats + 3 * n + i, z);
    }
}
"""


def _supported() -> str:
    """Why the model cannot run here, or '' where it can."""
    if platform.machine() not in ("x86_64", "AMD64"):
        return f"an x86-64 CPU is needed (this is {platform.machine()})"
    try:
        flags = open("/proc/cpuinfo").read()
    except OSError:
        return "/proc/cpuinfo is not readable (Linux is needed)"
    if " avx2" not in flags or " fma" not in flags:
        return "the CPU has no AVX2 and FMA"
    if shutil.which("g++") is None:
        return "g++ is not installed"
    return ""


def build(directory: str) -> ctypes.CDLL:
    """The model compiled into a shared library (``g++ -O3 -mavx2 -mfma``, fused multiply-adds as
    in the polynomial graphs), with the shipped polynomials' coefficients."""
    from torchquat import _polynomials

    def literal(values):
        return ", ".join(f"{v!r}f" for v in values)

    source = (_SOURCE.replace("HALF_COS_COEFFICIENTS", literal(_polynomials._HALF_COS_POLYNOMIAL))
              .replace("HALF_SINC_COEFFICIENTS", literal(_polynomials._HALF_SINC_POLYNOMIAL)))
    cpp, library = os.path.join(directory, "layout_model.cpp"), os.path.join(directory, "layout_model.so")
    with open(cpp, "w") as f:
        f.write(source)
    subprocess.run(["g++", "-O3", "-mavx2", "-mfma", "-ffp-contract=fast", "-std=c++17", "-shared", "-fPIC",
                    cpp, "-o", library], check=True)
    lib = ctypes.CDLL(library)
    lib.euler_rows.argtypes = (ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long)
    lib.euler_planes.argtypes = (ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long)
    return lib


def model_calls(lib: ctypes.CDLL, angles: torch.Tensor):
    """Each variant as a call that writes its preallocated output, and a function that returns it
    as ``(n, 4)`` rows: ``{name: (call, result)}``. ``angles``: ``(n, 3)`` float32, n a multiple of 8."""
    n = angles.shape[0]
    rows = torch.empty(n, 4)
    planes_in, planes_out = angles.t().contiguous(), torch.empty(4, n)
    calls = {name: ((lambda v=v: lib.euler_rows(v, angles.data_ptr(), rows.data_ptr(), n)), lambda: rows)
             for v, name in enumerate(VARIANTS[:4])}
    calls["planes"] = (lambda: lib.euler_planes(planes_in.data_ptr(), planes_out.data_ptr(), n), lambda: planes_out.t())
    return calls


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=1_000_000, help="rows (rounded down to a multiple of 8)")
    parser.add_argument("--rounds", type=int, default=40,
                        help="interleaved rounds; each times every variant once (default: %(default)s)")
    parser.add_argument("--min-run-time", type=float, default=0.05,
                        help="seconds of blocked_autorange per measurement (default: %(default)s)")
    parser.add_argument("--compiled", action="store_true", help="also time torchquat's compiled kernel")
    args = parser.parse_args(argv)
    why = _supported()
    if why:
        print(f"layout_model: {why}", file=sys.stderr)
        return 2
    import torchquat
    from torchquat.bench import timing as _timing

    torch.set_num_threads(1)
    n = max(8, args.n // 8 * 8)
    generator = torch.Generator().manual_seed(0)
    angles = (torch.rand(n, 3, generator=generator) * 2.0 - 1.0) * math.pi
    expected = torchquat.euler_to_quat(angles.double(), "ZYX")
    floor_name = "floor (the bench's: `out.copy_(src)`, (n, 4))"
    timed, errors = {floor_name: _timing.floor_fn(n, 3, (4,), torch.float32)}, {}
    was_compiled = torchquat.compiled_kernels_enabled()
    with tempfile.TemporaryDirectory() as directory:
        for name, (call, result) in model_calls(build(directory), angles).items():
            call()
            errors[name] = (result().double() - expected).abs().max().item()
            timed[name] = call
        try:
            if args.compiled:
                torchquat.use_compiled_kernels(True)
                compiled = lambda: torchquat.euler_to_quat(angles, "ZYX")  # (no gradient: the inference graph)
                errors["torchquat compiled"] = (compiled().double() - expected).abs().max().item()
                timed["torchquat compiled"] = compiled
            times = {name: [] for name in timed}
            for _ in range(args.rounds):
                for name, call in timed.items():
                    times[name].append(_timing.measure(call, args.min_run_time, threads=1).median * 1e3)
        finally:
            torchquat.use_compiled_kernels(was_compiled)
    floor = statistics.median(times[floor_name])
    print(f"Euler ZYX -> quat, {n:,} float32 rows, one thread, {args.rounds} interleaved rounds "
          f"(median of the rounds' blocked_autorange medians), ms; max error against float64")
    print("| variant | ms | x floor | max error |")
    print("|---|---:|---:|---:|")
    for name, values in times.items():
        ms = statistics.median(values)
        error = f"{errors[name]:.1e}" if name in errors else ""
        print(f"| {name} | {ms:.2f} | {ms / floor:.2f} | {error} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

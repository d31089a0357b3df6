"""The arithmetic of the exports, of the synthetic generators and of calibrate's keypoint refinement: 3 x 3
matrices, rotations, rotation vectors, dot products, sines, exponentials and powers in IEEE basic operations only.

An export writes numbers computed from the bundle's, a synthetic generator the truth it drew (``synth``'s design,
projectors and tent, ``kinect-synth``'s poses) and the images it rendered from it; every machine must write the
same bits for the same input or seed (README, "Same result on every machine"). Three kinds of library call do
not give the same bits on every CPU (measured by ``bench/same_bytes.py``, docs/benchmarks.md):

- BLAS and LAPACK (``@``, ``np.dot``, ``np.linalg.svd`` / ``solve`` / ``det``, scipy's ``Rotation.from_matrix``,
  which orthonormalises by SVD): OpenBLAS picks its kernels by CPU, and they sum in other orders, with or without
  fused multiply-adds;
- numpy's transcendental ufuncs (``np.arctan2``, ``np.arccos``, ``np.exp``, ...): on an AVX-512 CPU numpy takes
  Intel's SVML routines, elsewhere the C library's;
- the C library's own (``math.atan2``, ``np.sin``): glibc picks a variant compiled with or without FMA by CPU.

What every CPU does alike is an IEEE basic operation (+, -, *, /, sqrt: correctly rounded) on one element at a
time, in an order the program fixes. So this module writes every product out term by term (left to right),
inverts through cofactors, finds the nearest rotation by Newton's iteration for the polar factor, and takes the
one angle a rotation vector needs from its own arctangent (a table of 9 exact constants and 8 terms of the
series). Every function is vectorised over leading axes with numpy's elementwise operations (no reduction: numpy
may sum a reduction in SIMD-width blocks). The exporters take every computed number from here, the synthetic
generators every product that reaches a file (``tests/test_synth_exact.py`` holds them to it). A float32 array
stays float32 (the renderer's shading); anything else is computed in float64.
"""
from __future__ import annotations

import numpy as np

#: atan(k / 8), k = 0..8, each the double nearest the true value (computed in 60-digit decimal arithmetic).
_ATAN_EIGHTHS = np.array([0.0, 0.12435499454676144, 0.24497866312686414, 0.35877067027057225, 0.4636476090008061,
                          0.5585993153435624, 0.6435011087932844, 0.7188299996216245, 0.7853981633974483])
_HALF_PI = 1.5707963267948966
#: Newton steps for the polar factor: from a rotation orthonormal to 1e-5 the error squares each step (1e-10,
#: 1e-20): converged in 3; the rest is margin. A fixed count, so that a camera's bits do not depend on the others.
_POLAR_STEPS = 6


def _floats(x: np.ndarray) -> np.ndarray:
    """``x`` as a float array: float32 and float64 kept, anything else float64."""
    x = np.asarray(x)
    return x if x.dtype in (np.float32, np.float64) else x.astype(float)


def matmul3(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(..., 3, 3) @ (..., 3, 3), each entry a0*b0 + a1*b1 + a2*b2 in that order."""
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    return (A[..., :, 0, None] * B[..., None, 0, :] + A[..., :, 1, None] * B[..., None, 1, :]
            + A[..., :, 2, None] * B[..., None, 2, :])


def matvec3(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) @ (..., 3), each entry a0*v0 + a1*v1 + a2*v2 in that order (broadcast: one matrix and (N, 3)
    points gives each point's product, ``points @ A.T``)."""
    A, v = _floats(A), _floats(v)
    return A[..., :, 0] * v[..., None, 0] + A[..., :, 1] * v[..., None, 1] + A[..., :, 2] * v[..., None, 2]


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) a0*b0 + a1*b1 + a2*b2 in that order, of (..., 3) vectors (not a BLAS dot, not an einsum)."""
    a, b = _floats(a), _floats(b)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm3(a: np.ndarray) -> np.ndarray:
    """(...,) Euclidean length of (..., 3) vectors: the square root of :func:`dot3`."""
    return np.sqrt(dot3(a, a))


def unit3(a: np.ndarray) -> np.ndarray:
    """(..., 3) vectors divided by their :func:`norm3`."""
    return _floats(a) / norm3(a)[..., None]


#: ln 2 in two parts (Cody and Waite): the first with its last 11 bits zero, so that k * _LN2_HI is exact for
#: |k| < 2^11; the second the rest.
_LN2_HI, _LN2_LO = 0.6931471803691238, 1.9082149292705877e-10
#: 1 / n! for the series of exp(r), |r| <= ln(2) / 2: the first term left out (r^14 / 14!) is below 2e-17 of it.
_EXP_TERMS = tuple(1.0 / np.prod(np.arange(1.0, n + 1.0)) for n in range(14))


def exp(x: np.ndarray) -> np.ndarray:
    """e^x (float64) in basic operations: x = k ln 2 + r, |r| <= ln(2) / 2, the series of e^r by Horner's rule,
    times 2^k (``np.ldexp``: exact). Within 2 units in the last place of libm's for x in [-700, 700]
    (``tests/test_synth_exact.py``); numpy's ``np.exp`` is Intel's SVML on an AVX-512 CPU."""
    x = np.asarray(x, dtype=float)
    k = np.rint(x / _LN2_HI)
    r = (x - k * _LN2_HI) - k * _LN2_LO
    s = _EXP_TERMS[-1]
    for c in _EXP_TERMS[-2::-1]:
        s = c + r * s
    return np.ldexp(s, k.astype(np.int64))


#: pi / 2 in three parts (fdlibm's): the first two of 33 significant bits, so that k times each is exact for
#: |k| < 2^20 (|x| below 1.6e6 rad).
_PIO2_1, _PIO2_2, _PIO2_3 = 1.57079632673412561417e+00, 6.07710050630396597660e-11, 2.02226624871116645580e-21
#: (-1)^n / (2n + 1)! and (-1)^n / (2n)!, n = 0..9: for |r| <= pi / 4 the first terms left out are below 1e-20.
_SIN_TERMS = tuple((-1.0) ** n / float(np.prod(np.arange(1.0, 2 * n + 2.0))) for n in range(10))
_COS_TERMS = tuple((-1.0) ** n / float(np.prod(np.arange(1.0, 2 * n + 1.0))) for n in range(10))


def sincos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) (float64) in basic operations: x = k pi / 2 + r, |r| <= pi / 4, the two series by Horner's
    rule, the quadrant from k. Within 2 units in the last place of libm's on uniform draws up to |x| = 1e5 (and
    1.2e-16 absolute near its zeros; ``tests/test_synth_exact.py``); ``np.sin`` / ``np.cos`` are glibc's, whose
    variants with and without FMA differ on some inputs."""
    x = np.asarray(x, dtype=float)
    k = np.rint(x / _PIO2_1)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    r2 = r * r
    s, c = _SIN_TERMS[-1], _COS_TERMS[-1]
    for a, b in zip(_SIN_TERMS[-2::-1], _COS_TERMS[-2::-1]):
        s, c = a + r2 * s, b + r2 * c
    s = r * s
    q = np.mod(k, 4.0)
    sin = np.where(q == 0.0, s, np.where(q == 1.0, c, np.where(q == 2.0, -s, -c)))
    cos = np.where(q == 0.0, c, np.where(q == 1.0, -s, np.where(q == 2.0, -c, s)))
    return sin, cos


def sin(x: np.ndarray) -> np.ndarray:
    """sin x: :func:`sincos`'s first."""
    return sincos(x)[0]


def cos(x: np.ndarray) -> np.ndarray:
    """cos x: :func:`sincos`'s second."""
    return sincos(x)[1]


def rotvec_matrix(r: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation of the (..., 3) rotation vectors (axis times angle, rad) through their unit quaternion
    (as scipy's ``Rotation.from_rotvec(r).as_matrix()``, whose sine and cosine are the C library's): the angle's
    half by :func:`sincos`, sin(h) / angle by its series below 1e-3 rad."""
    r = np.asarray(r, dtype=float)
    theta = norm3(r)
    s_half, c_half = sincos(0.5 * theta)
    t2 = theta * theta
    scale = np.where(theta > 1e-3, s_half / np.where(theta > 1e-3, theta, 1.0), 0.5 - t2 / 48.0 + t2 * t2 / 3840.0)
    x, y, z, w = r[..., 0] * scale, r[..., 1] * scale, r[..., 2] * scale, c_half
    return np.stack([np.stack([w * w + x * x - y * y - z * z, 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)], -1),
                     np.stack([2.0 * (x * y + z * w), w * w - x * x + y * y - z * z, 2.0 * (y * z - x * w)], -1),
                     np.stack([2.0 * (x * z - y * w), 2.0 * (y * z + x * w), w * w - x * x - y * y + z * z], -1)],
                    axis=-2)


#: The largest m of a power k / 2^m :func:`power_dyadic` takes as square roots (gamma 0.625 = 5 / 8: m = 3).
_DYADIC_ROOTS = 6


def power_dyadic(x: np.ndarray, p: float) -> np.ndarray:
    """``x ** p`` for x >= 0 and p = k / 2^m (k a whole number below 64, m <= 6): x^k by multiplications in a fixed
    order, then m square roots (the roots first where x^k would leave the normal floats), so the same bits on every
    CPU (``np.power`` is Intel's SVML on AVX-512 CPUs, the C library's elsewhere). Within 2 units in the last place
    of libm's power for the powers of ``tests/test_synth_exact.py`` (x in [0, 1]). Any other ``p``: ValueError."""
    k, m = float(p), 0
    while not k.is_integer() and m < _DYADIC_ROOTS:
        k, m = k * 2.0, m + 1
    if not (k.is_integer() and 0 <= k < 64):
        raise ValueError(f"power_dyadic: {p} is not k / 2^m with k < 64, m <= {_DYADIC_ROOTS}")
    x = _floats(x)
    first, root = np.ones_like(x), x  # the power first (the more accurate), or the roots first (no underflow)
    for _ in range(m):
        root = np.sqrt(root)
    then = np.ones_like(x)
    for _ in range(int(k)):
        first, then = first * x, then * root
    for _ in range(m):
        first = np.sqrt(first)
    tiny = np.finfo(x.dtype).tiny
    return np.where((first >= tiny) | (x == 0.0), first, then)


def transpose3(A: np.ndarray) -> np.ndarray:
    return np.swapaxes(np.asarray(A, dtype=float), -1, -2)


def cofactor3(A: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cofactor matrix: row i is the cross product of the other two rows (inverse = cofactor.T / det)."""
    A = np.asarray(A, dtype=float)
    r0, r1, r2 = A[..., 0, :], A[..., 1, :], A[..., 2, :]
    return np.stack([cross3(r1, r2), cross3(r2, r0), cross3(r0, r1)], axis=-2)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1], a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def det3(A: np.ndarray) -> np.ndarray:
    """(...,) determinant: row 0 dotted with its cofactor row."""
    A = np.asarray(A, dtype=float)
    return dot3(A[..., 0, :], cross3(A[..., 1, :], A[..., 2, :]))


def solve3(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) x with A x = b, through the cofactors (A well conditioned: a rotation, a camera matrix)."""
    return matvec3(transpose3(cofactor3(A)), b) / det3(A)[..., None]


def nearest_rotation(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the rotation nearest ``R`` (its orthogonal polar factor, as U @ Vt of its SVD) for a matrix
    with positive determinant: Newton's iteration X <- (X + X^-T) / 2, X^-T = cofactor(X) / det(X)."""
    X = np.asarray(R, dtype=float)
    for _ in range(_POLAR_STEPS):
        X = 0.5 * (X + cofactor3(X) / det3(X)[..., None, None])
    return X


def rotation_exact(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The nearest rotation to ``R`` (..., 3, 3) and the translation (..., 3) that keeps the camera centre
    ``-R^-1 t`` where it was.

    A bundle's R is orthonormal only to the digits its file keeps (~1e-10 for the real Panoptic files); every other
    format stores a true rotation (quaternion, Rodrigues vector). Keeping the centre makes the change an angle of
    that size (~1e-7 px) at every depth, instead of an offset of |R' - R| |X| that grows near the camera.
    """
    R_exact = nearest_rotation(R)
    kept = -solve3(R, t)  # the camera centre
    return R_exact, -matvec3(R_exact, kept)


def centre(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(..., 3) camera centre ``-R^T t`` of a rotation ``R`` and translation ``t``."""
    return -matvec3(transpose3(R), t)


def _atan_unit(z: np.ndarray) -> np.ndarray:
    """atan(z) for 0 <= z <= 1: atan(k/8) + atan(u), u = (z - k/8) / (1 + z k/8), |u| <= 1/16, 8 terms of the
    series (the first left out is below 1e-21 of u)."""
    k = np.rint(z * 8.0)
    c = k / 8.0
    u = (z - c) / (1.0 + z * c)
    u2 = u * u
    s = -1.0 / 15.0
    for n in (13, 11, 9, 7, 5, 3):
        s = (1.0 if n % 4 == 1 else -1.0) / n + u2 * s
    return _ATAN_EIGHTHS[k.astype(int)] + (u + u * (u2 * s))


def atan_ratio(s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """atan2(s, c) for s >= 0, c >= 0 (not both 0), in [0, pi/2], within 2 units in the last place of libm's
    (``tests/test_export_exact.py``)."""
    s, c = np.asarray(s, dtype=float), np.asarray(c, dtype=float)
    low = s <= c
    z = np.where(low, s, c) / np.where(low, c, s)
    a = _atan_unit(z)
    return np.where(low, a, _HALF_PI - a)


def quaternion(R: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternion [w, x, y, z], w >= 0, of a rotation (..., 3, 3) (Shepperd: from the largest of the
    trace and the diagonal, the others by division)."""
    R = np.asarray(R, dtype=float)
    d0, d1, d2 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    tr = d0 + d1 + d2
    choice = np.argmax(np.stack([tr, d0, d1, d2], axis=-1), axis=-1)
    s21, s02, s10 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    a21, a02, a10 = R[..., 2, 1] + R[..., 1, 2], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 0] + R[..., 0, 1]
    big = np.stack([1.0 + tr, 1.0 + d0 - d1 - d2, 1.0 - d0 + d1 - d2, 1.0 - d0 - d1 + d2], axis=-1)
    b = np.sqrt(np.take_along_axis(big, choice[..., None], axis=-1)[..., 0])  # 2 |q_choice|
    rows = np.stack([np.stack([b * b, s21, s02, s10], -1), np.stack([s21, b * b, a10, a02], -1),
                     np.stack([s02, a10, b * b, a21], -1), np.stack([s10, a02, a21, b * b], -1)], axis=-2)
    q = np.take_along_axis(rows, choice[..., None, None], axis=-2)[..., 0, :] / (2.0 * b[..., None])
    norm = np.sqrt(q[..., 0] * q[..., 0] + q[..., 1] * q[..., 1] + q[..., 2] * q[..., 2] + q[..., 3] * q[..., 3])
    q = q / norm[..., None]
    return np.where(q[..., :1] < 0.0, -q, q)


def rotvec(R: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vector (axis times angle in [0, pi], rad) of a rotation (..., 3, 3)."""
    q = quaternion(R)
    v = q[..., 1:]
    sin_half = np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])
    angle = 2.0 * atan_ratio(sin_half, q[..., 0])
    scale = np.where(sin_half > 0.0, angle / np.where(sin_half > 0.0, sin_half, 1.0), 2.0)
    return v * scale[..., None]

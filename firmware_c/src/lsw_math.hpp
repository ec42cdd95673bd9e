/*
 * lsw_math.hpp - the elementary functions VQF calls (sin, cos, tan, exp, asin, acos, atan2),
 * written here so that the host library and the Cortex-M4 firmware compute them with the same
 * operations in the same order: the same bits on both (glibc's libm and newlib's differ in the
 * last bit now and then, and VQF's state carries such a bit on). Internal to src/lsw_vqf.cpp.
 *
 * Each function is a template over float and double and uses only +, -, *, /, sqrt (all IEEE
 * correctly rounded on both targets, compiled with -ffp-contract=off) and comparisons: argument
 * reduction by a constant split in parts (Cody-Waite), then a Taylor polynomial in Horner form on
 * the reduced range, with enough terms that truncation is below half an ulp of the result type.
 *
 * Specification, measured against float64 (tests/test_lsw_math.py):
 *   sin, cos  float: within 2 ulp for |x| <= 100, absolute error below 1e-7 for |x| <= 12,868 (2^13
 *             quarter turns; VQF's largest argument, half a step's turn at the pipeline's input
 *             range, is 4,330); beyond, the reduction is done in double; double: within 2 ulp for
 *             |x| <= 2^20 pi/2. No Payne-Hanek reduction: huge arguments lose accuracy. +-Inf, NaN: NaN.
 *   tan       float: within 4 ulp for |x| <= 100; double: within 3 ulp for |x| <= 2^20 pi/2.
 *   exp       within 2 ulp; +Inf above the largest finite result, 0 below the smallest subnormal.
 *   asin, acos  within 3 ulp on [-1, 1]; NaN outside it.
 *   atan2     within 3 ulp; C99's signed zeros and infinities; NaN if either argument is.
 */
#ifndef LSW_MATH_HPP
#define LSW_MATH_HPP

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

namespace lsw_math {

/** The constants of one precision: each split in a high part and the rest. */
template <typename T> struct Consts;

template <> struct Consts<float> {
    /* pi/2 in three parts: P1 has 8 bits and P2 11, so k * P1 and k * P2 are exact for k < 2^13 */
    static constexpr float pio2_1 = 0x1.92p+0f, pio2_2 = 0x1.fb4p-12f, pio2_3 = 0x1.4442d2p-24f;
    static constexpr float reduce_max = 8192.0f; /* largest quarter-turn count of the float path */
    static constexpr float pio2_hi = 0x1.921fb6p+0f, pio2_lo = -0x1.777a5cp-25f;
    static constexpr float pio6_hi = 0x1.0c1524p-1f, pio6_lo = -0x1.f4a326p-27f;
    static constexpr float sqrt3 = 0x1.bb67aep+0f, tan_pio12 = 0x1.126146p-2f;
    /* ln 2 in three parts (12 and 11 bits); exp overflows above, underflows to 0 below */
    static constexpr float ln2_1 = 0x1.62cp-1f, ln2_2 = 0x1.214p-12f, ln2_3 = 0x1.fbe8e8p-23f;
    static constexpr float log2e = 0x1.715476p+0f, exp_max = 0x1.62e42ep+6f, exp_min = -0x1.9fe368p+6f;
    static constexpr int sin_terms = 5, cos_terms = 5, exp_terms = 8, asin_terms = 10, atan_terms = 6;
    static constexpr int exp_bias = 127, exp_shift = 23, exp_top = 127, exp_bottom = -126;
    using Bits = std::uint32_t;
};

template <> struct Consts<double> {
    static constexpr double pio2_1 = 0x1.921fb544p+0, pio2_2 = 0x1.0b4611a6p-34, pio2_3 = 0x1.3198a2e037073p-69;
    static constexpr double reduce_max = 1048576.0; /* 2^20: k * P1 exact (P1 has 33 bits) */
    static constexpr double pio2_hi = 0x1.921fb54442d18p+0, pio2_lo = 0x1.1a62633145c07p-54;
    static constexpr double pio6_hi = 0x1.0c152382d7366p-1, pio6_lo = -0x1.ee6913347c2a6p-55;
    static constexpr double sqrt3 = 0x1.bb67ae8584caap+0, tan_pio12 = 0x1.126145e9ecd56p-2;
    static constexpr double ln2_1 = 0x1.62e42feep-1, ln2_2 = 0x1.a39ef356p-33, ln2_3 = 0x1.93c7673007e5fp-65;
    static constexpr double log2e = 0x1.71547652b82fep+0, exp_max = 0x1.62e42fefa39efp+9,
                            exp_min = -0x1.74385446d71c3p+9;
    static constexpr int sin_terms = 8, cos_terms = 9, exp_terms = 13, asin_terms = 26, atan_terms = 13;
    static constexpr int exp_bias = 1023, exp_shift = 52, exp_top = 1023, exp_bottom = -1022;
    using Bits = std::uint64_t;
};

/** The polynomials' coefficients, computed by the compiler (the same bits for every target). */
template <typename T> struct Coeffs {
    T sin[Consts<T>::sin_terms];   /* (-1)^(n+1) / (2n+3)! */
    T cos[Consts<T>::cos_terms];   /* (-1)^n / (2n+4)! */
    T exp[Consts<T>::exp_terms + 1]; /* 1 / n! */
    T asin[Consts<T>::asin_terms]; /* (2n)! / (4^n n!^2 (2n+1)), n >= 1 */
    T atan[Consts<T>::atan_terms]; /* (-1)^n / (2n+1), n >= 1 */
    constexpr Coeffs() : sin(), cos(), exp(), asin(), atan()
    {
        T fact = T(1);
        for (int n = 0; n < Consts<T>::sin_terms; n++) {
            fact = fact * T((2 * n + 2) * (2 * n + 3));
            sin[n] = (n % 2 == 0 ? T(-1) : T(1)) / fact;
        }
        fact = T(2);
        for (int n = 0; n < Consts<T>::cos_terms; n++) {
            fact = fact * T((2 * n + 3) * (2 * n + 4));
            cos[n] = (n % 2 == 0 ? T(1) : T(-1)) / fact;
        }
        fact = T(1);
        for (int n = 0; n <= Consts<T>::exp_terms; n++) {
            fact = n > 0 ? fact * T(n) : fact;
            exp[n] = T(1) / fact;
        }
        T c = T(1);
        for (int n = 1; n <= Consts<T>::asin_terms; n++) {
            c = c * T(2 * n - 1) / T(2 * n);
            asin[n - 1] = c / T(2 * n + 1);
        }
        for (int n = 1; n <= Consts<T>::atan_terms; n++) {
            atan[n - 1] = (n % 2 == 0 ? T(1) : T(-1)) / T(2 * n + 1);
        }
    }
};

template <typename T> constexpr Coeffs<T> coeffs{};

/** x rounded to the nearest integer, halves away from zero (no libm; |x| >= 2^52 is one). */
template <typename T> inline T round_int(T x)
{
    T a = x < T(0) ? -x : x;
    if (!(a < T(4503599627370496.0))) {
        return x;
    }
    T r = T(static_cast<std::int64_t>(a + T(0.5)));
    return x < T(0) ? -r : r;
}

/** 2^k for k within the normal exponents, built from its bits. */
template <typename T> inline T pow2(int k)
{
    using C = Consts<T>;
    typename C::Bits bits = static_cast<typename C::Bits>(k + C::exp_bias) << C::exp_shift;
    T out;
    std::memcpy(&out, &bits, sizeof out);
    return out;
}

/** sin r on |r| <= pi/4: r + r z (-1/3! + z (1/5! - ...)), z = r^2. */
template <typename T> inline T sin_poly(T r)
{
    T z = r * r, p = T(0);
    for (int n = Consts<T>::sin_terms - 1; n >= 0; n--) {
        p = coeffs<T>.sin[n] + z * p;
    }
    return r + r * (z * p);
}

/** cos r on |r| <= pi/4: 1 - z/2 + z^2 (1/4! - z (1/6! - ...)). */
template <typename T> inline T cos_poly(T r)
{
    T z = r * r, p = T(0);
    for (int n = Consts<T>::cos_terms - 1; n >= 0; n--) {
        p = coeffs<T>.cos[n] + z * p;
    }
    T h = T(0.5) * z;
    return (T(1) - h) + z * (z * p);
}

/** x = k pi/2 + r, |r| <= about pi/4; returns k mod 4. x finite. */
template <typename T> inline int reduce(T x, T *r)
{
    using C = Consts<T>;
    T k = round_int(x * (T(1) / C::pio2_hi));
    T a = k < T(0) ? -k : k;
    if (a < C::reduce_max) { /* the common case */
        *r = ((x - k * C::pio2_1) - k * C::pio2_2) - k * C::pio2_3;
    } else { /* rare: the parts in double (a float argument) or less exact (a huge one) */
        double kd = round_int(static_cast<double>(x) * (1.0 / Consts<double>::pio2_hi));
        double rd = ((static_cast<double>(x) - kd * Consts<double>::pio2_1) - kd * Consts<double>::pio2_2) -
                    kd * Consts<double>::pio2_3;
        *r = static_cast<T>(rd);
        k = static_cast<T>(std::fmod(kd, 4.0)); /* exact in every libm */
    }
    std::int64_t q = static_cast<std::int64_t>(k);
    return static_cast<int>(q & 3);
}

template <typename T> inline T sin(T x)
{
    if (!(x - x == T(0))) {
        return std::numeric_limits<T>::quiet_NaN(); /* NaN, +-Inf */
    }
    T r;
    int q = reduce(x, &r);
    T v = (q & 1) ? cos_poly(r) : sin_poly(r);
    return (q & 2) ? -v : v;
}

template <typename T> inline T cos(T x)
{
    if (!(x - x == T(0))) {
        return std::numeric_limits<T>::quiet_NaN();
    }
    T r;
    int q = reduce(x, &r);
    T v = (q & 1) ? sin_poly(r) : cos_poly(r);
    return ((q + 1) & 2) ? -v : v;
}

template <typename T> inline T tan(T x)
{
    if (!(x - x == T(0))) {
        return std::numeric_limits<T>::quiet_NaN();
    }
    T r;
    int q = reduce(x, &r);
    T s = sin_poly(r), c = cos_poly(r);
    return (q & 1) ? -c / s : s / c;
}

template <typename T> inline T exp(T x)
{
    using C = Consts<T>;
    if (x != x) {
        return x;
    }
    if (x > C::exp_max) {
        return std::numeric_limits<T>::infinity();
    }
    if (x < C::exp_min) {
        return T(0);
    }
    T k = round_int(x * C::log2e);
    T r = ((x - k * C::ln2_1) - k * C::ln2_2) - k * C::ln2_3;
    T p = T(0);
    for (int n = Consts<T>::exp_terms; n >= 0; n--) {
        p = coeffs<T>.exp[n] + r * p;
    }
    int ki = static_cast<int>(k);
    int k1 = ki / 2, k2 = ki - k1; /* each within the normal exponents */
    return (p * pow2<T>(k1)) * pow2<T>(k2);
}

/** asin x on |x| <= 1/2: x + x z P(z), z = x^2, P Taylor's (2n)! / (4^n n!^2 (2n+1)). */
template <typename T> inline T asin_poly(T x)
{
    T z = x * x, p = T(0);
    for (int n = Consts<T>::asin_terms - 1; n >= 0; n--) {
        p = coeffs<T>.asin[n] + z * p;
    }
    return x + x * (z * p);
}

template <typename T> inline T asin(T x)
{
    using C = Consts<T>;
    T a = x < T(0) ? -x : x;
    if (!(a <= T(1))) {
        return std::numeric_limits<T>::quiet_NaN();
    }
    if (a <= T(0.5)) {
        return asin_poly(x);
    }
    T s = std::sqrt((T(1) - a) * T(0.5)); /* asin a = pi/2 - 2 asin s */
    T v = C::pio2_hi - (T(2) * asin_poly(s) - C::pio2_lo);
    return x < T(0) ? -v : v;
}

template <typename T> inline T acos(T x)
{
    using C = Consts<T>;
    T a = x < T(0) ? -x : x;
    if (!(a <= T(1))) {
        return std::numeric_limits<T>::quiet_NaN();
    }
    if (a <= T(0.5)) {
        return C::pio2_hi - (asin_poly(x) - C::pio2_lo);
    }
    T v = T(2) * asin_poly(std::sqrt((T(1) - a) * T(0.5)));
    return x > T(0) ? v : T(2) * C::pio2_hi - (v - T(2) * C::pio2_lo);
}

/** atan a for 0 <= a <= 1 (pi/6 + atan of the turned argument above tan(pi/12)). */
template <typename T> inline T atan_unit(T a)
{
    using C = Consts<T>;
    int turned = a > C::tan_pio12;
    if (turned) {
        a = (a * C::sqrt3 - T(1)) / (a + C::sqrt3);
    }
    T z = a * a, p = T(0);
    for (int n = Consts<T>::atan_terms - 1; n >= 0; n--) {
        p = coeffs<T>.atan[n] + z * p;
    }
    T v = a + a * (z * p);
    return turned ? C::pio6_hi + (v + C::pio6_lo) : v;
}

template <typename T> inline T atan2(T y, T x)
{
    using C = Consts<T>;
    if (x != x || y != y) {
        return x + y;
    }
    T ay = y < T(0) ? -y : y, ax = x < T(0) ? -x : x;
    int x_neg = std::signbit(x), y_neg = std::signbit(y);
    T v;
    if (ay == T(0)) {
        v = x_neg ? T(2) * C::pio2_hi : T(0);
    } else if (ax == std::numeric_limits<T>::infinity() && ay == ax) {
        v = x_neg ? T(3) * (C::pio2_hi * T(0.5)) : C::pio2_hi * T(0.5);
    } else {
        T u = ay <= ax ? atan_unit(ay / ax) : C::pio2_hi - (atan_unit(ax / ay) - C::pio2_lo);
        v = x_neg ? T(2) * C::pio2_hi - (u - T(2) * C::pio2_lo) : u;
    }
    return y_neg ? -v : v;
}

} /* namespace lsw_math */

/*
 * What VQF's `std::` names resolve to inside src/lsw_vqf.cpp: the functions above, and the rest
 * (exact operations, algorithms, limits) from the C++ library itself. The overloads are std's:
 * float for float, double for double, double for an integer.
 */
namespace lsw_math_std {
using ::std::copy;
using ::std::fabs;
using ::std::fill;
using ::std::isnan;
using ::std::max;
using ::std::min;
using ::std::numeric_limits;
using ::std::sqrt;
inline float sin(float x) { return lsw_math::sin(x); }
inline double sin(double x) { return lsw_math::sin(x); }
inline float cos(float x) { return lsw_math::cos(x); }
inline double cos(double x) { return lsw_math::cos(x); }
inline float tan(float x) { return lsw_math::tan(x); }
inline double tan(double x) { return lsw_math::tan(x); }
inline float exp(float x) { return lsw_math::exp(x); }
inline double exp(double x) { return lsw_math::exp(x); }
inline float asin(float x) { return lsw_math::asin(x); }
inline double asin(double x) { return lsw_math::asin(x); }
inline float acos(float x) { return lsw_math::acos(x); }
inline double acos(double x) { return lsw_math::acos(x); }
inline float atan2(float y, float x) { return lsw_math::atan2(y, x); }
inline double atan2(double y, double x) { return lsw_math::atan2(y, x); }
} /* namespace lsw_math_std */

#endif /* LSW_MATH_HPP */

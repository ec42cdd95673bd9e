/*
 * lsw_ff.hpp - float-float numbers: a value held as the unevaluated sum of two floats (hi + lo,
 * |lo| <= half an ulp of hi), about 44 bits of precision from single-precision operations only.
 * Internal to src/lsw_vqf.cpp: the single-precision VQF keeps its accelerometer low-pass state in
 * it (docs/kernel.md, "VQF's precision").
 *
 * The operations are the classic error-free transformations (Dekker 1971; Shewchuk 1997): every
 * step is an IEEE operation correctly rounded on every target, or an exact product error however
 * it is found (two_prod_err), so the host library and the firmware compute the same bits.
 * Addition is the "sloppy" one: its error is below about 2^-44 of the larger operand, not of the
 * result, which is what a filter's state needs. Only the operations VQF's filter code uses.
 */
#ifndef LSW_FF_HPP
#define LSW_FF_HPP

#include <cmath>

struct lsw_ff {
    float hi, lo;

    lsw_ff() = default;
    constexpr lsw_ff(float h, float l) : hi(h), lo(l) {}
    constexpr lsw_ff(float x) : hi(x), lo(0.0f) {} /* implicit: mixed arithmetic widens floats */
    constexpr lsw_ff(int x) : hi(static_cast<float>(x)), lo(0.0f) {} /* VQF's literals: C(0), C(1) */
    explicit lsw_ff(double x) : hi(static_cast<float>(x)), lo(static_cast<float>(x - static_cast<double>(hi))) {}
    /* the float nearest to hi + lo: hi, as every operation below leaves it */
    explicit operator float() const { return hi; }
};

namespace lsw_ff_ops {

/** a + b as hi + lo exactly, if |a| >= |b| or a is 0. */
static inline lsw_ff fast_two_sum(float a, float b)
{
    float s = a + b;
    return lsw_ff(s, b - (s - a));
}

/** a + b as hi + lo exactly, any order. */
static inline lsw_ff two_sum(float a, float b)
{
    float s = a + b;
    float bb = s - a;
    return lsw_ff(s, (a - (s - bb)) + (b - bb));
}

/** a * b - p exactly, for p the rounded product a * b (barring underflow): one fused multiply-add
 * where the target has a fast one (the M4's VFMA.F32: 2,838 instructions per raw sample for VQF
 * 6D, against 3,018 with the split), else Dekker's splitting (a call to fmaf costs more than it
 * saves on x86-64 without -mfma); LSW_FF_NO_FMA forces the split. Exact either way: the same bits. */
static inline float two_prod_err(float a, float b, float p)
{
#if defined(__FP_FAST_FMAF) && !defined(LSW_FF_NO_FMA)
    return __builtin_fmaf(a, b, -p);
#else
    const float split = 4097.0f; /* 2^12 + 1: halves of 12 bits each */
    float ca = split * a, cb = split * b;
    float ah = ca - (ca - a), bh = cb - (cb - b);
    float al = a - ah, bl = b - bh;
    return ((ah * bh - p) + ah * bl + al * bh) + al * bl;
#endif
}

} /* namespace lsw_ff_ops */

static inline lsw_ff operator+(lsw_ff a, lsw_ff b)
{
    lsw_ff s = lsw_ff_ops::two_sum(a.hi, b.hi);
    return lsw_ff_ops::fast_two_sum(s.hi, s.lo + (a.lo + b.lo));
}

static inline lsw_ff operator-(lsw_ff a) { return lsw_ff(-a.hi, -a.lo); }
static inline lsw_ff operator-(lsw_ff a, lsw_ff b) { return a + (-b); }

static inline lsw_ff operator*(lsw_ff a, lsw_ff b)
{
    float p = a.hi * b.hi;
    float e = lsw_ff_ops::two_prod_err(a.hi, b.hi, p) + (a.hi * b.lo + a.lo * b.hi);
    return lsw_ff_ops::fast_two_sum(p, e);
}

static inline lsw_ff operator*(lsw_ff a, float b)
{
    float p = a.hi * b;
    float e = lsw_ff_ops::two_prod_err(a.hi, b, p) + a.lo * b;
    return lsw_ff_ops::fast_two_sum(p, e);
}

static inline lsw_ff operator*(float a, lsw_ff b) { return b * a; }

static inline lsw_ff operator/(lsw_ff a, lsw_ff b)
{
    float q = a.hi / b.hi;
    lsw_ff r = a - b * q;
    return lsw_ff_ops::fast_two_sum(q, r.hi / b.hi);
}

static inline lsw_ff &operator+=(lsw_ff &a, lsw_ff b) { return a = a + b; }
static inline lsw_ff &operator++(lsw_ff &a) { return a = a + lsw_ff(1.0f); }
static inline lsw_ff operator++(lsw_ff &a, int)
{
    lsw_ff old = a;
    ++a;
    return old;
}

namespace lsw_math_std {
static inline bool isnan(lsw_ff a) { return std::isnan(a.hi); }
}

#endif /* LSW_FF_HPP */

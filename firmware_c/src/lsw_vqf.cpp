/*
 * lsw_vqf.cpp - the C API of lsw_vqf.h over VQF's own C++ class.
 *
 * VQF's source (firmware_c/vqf: vqf.cpp and vqf.hpp of the `vqf` package, with the precision of its
 * filters made a type; its README says what changed) is compiled inside this file, once per
 * precision it is built in (fastsw_config.h: LSW_VQF_BOTH, LSW_VQF_DEFAULT_DOUBLE), each in a
 * namespace of its own:
 *   lsw_vqf_single  VQF's low-pass filter states, their coefficients and its 3x3 inverse in float,
 *                   but for the accelerometer low-pass filter's, in float-float (lsw_ff.hpp): no
 *                   soft-float double arithmetic per raw sample on a Cortex-M4;
 *   lsw_vqf_double  VQF as its authors built it (those in double, the rest float).
 * In both, VQF's `std::` names are lsw_math_std's (lsw_math.hpp): sin, cos, tan, exp, asin, acos
 * and atan2 from the same source on every target, so the host library and the firmware compute
 * the same bits.
 */
#include "lsw_vqf.h"

#include <assert.h>
#include <stddef.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>

#include "fastsw_config.h"
#include "lsw_ff.hpp"
#include "lsw_math.hpp"

#ifndef VQF_SINGLE_PRECISION
#error "VQF is built with -DVQF_SINGLE_PRECISION on every target (lsw_vqf.h)"
#endif

#define LSW_VQF_HAS_SINGLE (LSW_VQF_BOTH || !LSW_VQF_DEFAULT_DOUBLE)
#define LSW_VQF_HAS_DOUBLE (LSW_VQF_BOTH || LSW_VQF_DEFAULT_DOUBLE)

#if LSW_VQF_HAS_SINGLE
namespace lsw_vqf_single {
namespace std = ::lsw_math_std;
#define VQF_FILTER_REAL float
#define VQF_ACC_LP_REAL lsw_ff
#undef VQF_HPP
#include "vqf.cpp"
#undef VQF_FILTER_REAL
#undef VQF_ACC_LP_REAL
static_assert(sizeof(VQF) <= LSW_VQF_STORAGE, "LSW_VQF_STORAGE is too small for VQF");
static_assert(alignof(VQF) <= alignof(LswVqf), "LswVqf is not aligned for VQF");
} /* namespace lsw_vqf_single */
#endif

#if LSW_VQF_HAS_DOUBLE
namespace lsw_vqf_double {
namespace std = ::lsw_math_std;
#undef VQF_HPP
#include "vqf.cpp"
static_assert(sizeof(VQF) <= LSW_VQF_STORAGE, "LSW_VQF_STORAGE is too small for VQF");
static_assert(alignof(VQF) <= alignof(LswVqf), "LswVqf is not aligned for VQF");
} /* namespace lsw_vqf_double */
#endif

/** The filter of type F constructed in *v. */
template <typename F> static inline F *filter_as(const LswVqf *v)
{
    return std::launder(reinterpret_cast<F *>(const_cast<unsigned char *>(v->u.bytes)));
}

/** fn(filter) on the filter in *v, as the precision it was constructed in. */
template <typename Fn> static inline auto with_filter(const LswVqf *v, Fn fn)
{
#if LSW_VQF_HAS_SINGLE && LSW_VQF_HAS_DOUBLE
    if (v->precision == LSW_VQF_DOUBLE) {
        return fn(filter_as<lsw_vqf_double::VQF>(v));
    }
    return fn(filter_as<lsw_vqf_single::VQF>(v));
#elif LSW_VQF_HAS_DOUBLE
    return fn(filter_as<lsw_vqf_double::VQF>(v));
#else
    return fn(filter_as<lsw_vqf_single::VQF>(v));
#endif
}

/** lsw_math's function number fn (lsw_vqf.h: lsw_math_eval) at (x, y). */
template <typename T> static T math_at(int fn, T x, T y)
{
    switch (fn) {
    case 0: return lsw_math_std::sin(x);
    case 1: return lsw_math_std::cos(x);
    case 2: return lsw_math_std::tan(x);
    case 3: return lsw_math_std::exp(x);
    case 4: return lsw_math_std::asin(x);
    case 5: return lsw_math_std::acos(x);
    default: return lsw_math_std::atan2(y, x);
    }
}

extern "C" {

uint32_t lsw_vqf_init(LswVqf *v, float period_s, uint32_t precision)
{
    /* trivially destructible: storage may be reused or dropped */
#if LSW_VQF_HAS_DOUBLE
    if (precision == LSW_VQF_DOUBLE || !LSW_VQF_HAS_SINGLE) {
        v->precision = LSW_VQF_DOUBLE;
        new (v->u.bytes) lsw_vqf_double::VQF(period_s);
        return v->precision;
    }
#endif
#if LSW_VQF_HAS_SINGLE
    (void)precision;
    v->precision = LSW_VQF_SINGLE;
    new (v->u.bytes) lsw_vqf_single::VQF(period_s);
#endif
    return v->precision;
}

void lsw_vqf_reset(LswVqf *v)
{
    with_filter(v, [](auto *f) { f->resetState(); });
}

void lsw_vqf_set_rest_thresholds(LswVqf *v, float gyr_dps, float acc)
{
    with_filter(v, [&](auto *f) { f->setRestDetectionThresholds(gyr_dps, acc); });
}

void lsw_vqf_set_heading(LswVqf *v, const float heading[2])
{
    with_filter(v, [&](auto *f) {
        auto state = f->getState();
        state.gyrQuat[0] = heading[0];
        state.gyrQuat[1] = 0.0f;
        state.gyrQuat[2] = 0.0f;
        state.gyrQuat[3] = heading[1];
        f->setState(state);
    });
}

void lsw_vqf_gyr(LswVqf *v, const float gyr[3])
{
    with_filter(v, [&](auto *f) { f->updateGyr(gyr); });
}

void lsw_vqf_acc(LswVqf *v, const float acc[3])
{
    with_filter(v, [&](auto *f) { f->updateAcc(acc); });
}

void lsw_vqf_mag(LswVqf *v, const float mag[3])
{
    with_filter(v, [&](auto *f) { f->updateMag(mag); });
}

void lsw_vqf_quat(const LswVqf *v, int nine_d, float q[4])
{
    with_filter(v, [&](auto *f) {
        if (nine_d) {
            f->getQuat9D(q);
        } else {
            f->getQuat6D(q);
        }
    });
}

void lsw_vqf_bias(const LswVqf *v, float bias[3])
{
    with_filter(v, [&](auto *f) { (void)f->getBiasEstimate(bias); });
}

int lsw_vqf_rest(const LswVqf *v)
{
    return with_filter(v, [](auto *f) { return f->getRestDetected() ? 1 : 0; });
}

size_t lsw_vqf_size(const LswVqf *v)
{
    return with_filter(v, [](auto *f) { return sizeof *f; });
}

size_t lsw_math_eval(int fn, size_t n, const double *x, const double *y, double *out, int in_double)
{
    size_t k;
    for (k = 0u; k < n; k++) {
        double r;
        if (in_double) {
            r = math_at(fn, x[k], y[k]);
        } else {
            r = static_cast<double>(math_at(fn, static_cast<float>(x[k]), static_cast<float>(y[k])));
        }
        out[k] = r;
    }
    return n;
}

} /* extern "C" */

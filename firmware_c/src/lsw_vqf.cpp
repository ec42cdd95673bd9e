/*
 * lsw_vqf.cpp - the C API of lsw_vqf.h over VQF's own C++ class.
 *
 * VQF's source (vqf.cpp and vqf.hpp from the `vqf` package, unchanged) is compiled inside this
 * file, so that the one compile-time switch about it (LSW_VQF_FLOAT, fastsw_config.h) reaches it
 * and the Cortex-M4 build inlines VQF's updates into the calls below.
 */
#include "lsw_vqf.h"

#include <assert.h>
#include <stddef.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>

#include "fastsw_config.h"

#if LSW_VQF_FLOAT
/* VQF's double-precision filter states, coefficients and 3x3 inverse become float: every
 * standard header VQF includes is in above, so only VQF's own code sees this. */
#define double float
#endif
#include "vqf.cpp"
#if LSW_VQF_FLOAT
#undef double
#endif

#ifndef VQF_SINGLE_PRECISION
#error "VQF is built with -DVQF_SINGLE_PRECISION on every target (lsw_vqf.h)"
#endif

static_assert(sizeof(VQF) <= LSW_VQF_STORAGE, "LSW_VQF_STORAGE is too small for VQF");
static_assert(alignof(VQF) <= alignof(LswVqf), "LswVqf is not aligned for VQF");

/** The VQF object constructed in *v. */
static inline VQF *filter(LswVqf *v)
{
    return std::launder(reinterpret_cast<VQF *>(v->u.bytes));
}

static inline const VQF *filter(const LswVqf *v)
{
    return std::launder(reinterpret_cast<const VQF *>(v->u.bytes));
}

extern "C" {

void lsw_vqf_init(LswVqf *v, float period_s)
{
    new (v->u.bytes) VQF(period_s); /* trivially destructible: storage may be reused or dropped */
}

void lsw_vqf_reset(LswVqf *v)
{
    filter(v)->resetState();
}

void lsw_vqf_set_rest_thresholds(LswVqf *v, float gyr_dps, float acc)
{
    filter(v)->setRestDetectionThresholds(gyr_dps, acc);
}

void lsw_vqf_set_heading(LswVqf *v, const float heading[2])
{
    VQFState state = filter(v)->getState();
    state.gyrQuat[0] = heading[0];
    state.gyrQuat[1] = 0.0f;
    state.gyrQuat[2] = 0.0f;
    state.gyrQuat[3] = heading[1];
    filter(v)->setState(state);
}

void lsw_vqf_gyr(LswVqf *v, const float gyr[3])
{
    filter(v)->updateGyr(gyr);
}

void lsw_vqf_acc(LswVqf *v, const float acc[3])
{
    filter(v)->updateAcc(acc);
}

void lsw_vqf_mag(LswVqf *v, const float mag[3])
{
    filter(v)->updateMag(mag);
}

void lsw_vqf_quat(const LswVqf *v, int nine_d, float q[4])
{
    if (nine_d) {
        filter(v)->getQuat9D(q);
    } else {
        filter(v)->getQuat6D(q);
    }
}

void lsw_vqf_bias(const LswVqf *v, float bias[3])
{
    (void)filter(v)->getBiasEstimate(bias);
}

int lsw_vqf_rest(const LswVqf *v)
{
    return filter(v)->getRestDetected() ? 1 : 0;
}

size_t lsw_vqf_size(void)
{
    return sizeof(VQF);
}

} /* extern "C" */

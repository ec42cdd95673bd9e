/* lsw_clock.c - common-time stamps with a bounded slew (lsw_clock.h). */
#include "lsw_clock.h"

#include <math.h>

size_t lsw_stamp(const LswSync *sync, size_t n, const int64_t *slots, const double *local, double *out)
{
    size_t steps = 0;
    for (size_t i = 0; i < n; ++i) {
        const int64_t s = slots[i];
        const double L = local[i];
        const double at = sync->c_local[s];
        const double target = sync->a[s] + sync->b[s] * (L - sync->ref[s]);
        const int first = isnan(at);
        double c;
        if (first || sync->step[s]) {
            c = target;
            sync->stepped[s] = (uint8_t)!first;
            steps += !first;
            sync->step[s] = 0;
        } else {
            const double dt = L - at;
            const double pred = sync->c[s] + sync->b[s] * dt;
            const double limit = sync->slew * dt;
            double d = target - pred;
            if (d > limit)
                d = limit;
            else if (d < -limit)
                d = -limit;
            c = pred + d;
            sync->stepped[s] = 0;
        }
        if (!sync->ever[s])
            c = 0.0;
        sync->c[s] = c;
        sync->c_local[s] = L;
        out[i] = L + c;
    }
    return steps;
}

/* Struct sizes for the host bindings' load-time checks (lsw_abi.h). Host library only. */
#include "lsw_abi.h"

#include "fastsw.h"
#include "fastsw_batch.h"
#include "lsw_bank.h"
#include "lsw_clock.h"
#include "lsw_fuse.h"
#include "lsw_grid.h"
#include "lsw_imu.h"
#include "lsw_root.h"
#include "lsw_slimevr.h"

size_t lsw_abi_size(int which)
{
    switch (which) {
    case LSW_ABI_SETTINGS: return sizeof(FastswSettings);
    case LSW_ABI_POINT: return sizeof(FastswPoint);
    case LSW_ABI_BATCH_OUT: return sizeof(FastswBatchOut);
    case LSW_ABI_BANK_WIRE: return sizeof(LswBankWire);
    case LSW_ABI_SYNC: return sizeof(LswSync);
    case LSW_ABI_GRID_SETTINGS: return sizeof(LswGridSettings);
    case LSW_ABI_GRID_DEVICE: return sizeof(LswGridDevice);
    case LSW_ABI_SVR_TRACKER: return sizeof(LswSvrTracker);
    case LSW_ABI_SVR_ROUTE: return sizeof(LswSvrRoute);
    case LSW_ABI_SVR_SLOW: return sizeof(LswSvrSlow);
    case LSW_ABI_RAW_SAMPLE: return sizeof(LswRawSample);
    case LSW_ABI_IMU_SETTINGS: return sizeof(LswImuSettings);
    case LSW_ABI_FUSE_ROWS: return sizeof(LswFuseRows);
    case LSW_ABI_ROOT_STATE: return sizeof(LswRootState);
    case LSW_ABI_ROOT_CONST: return sizeof(LswRootConst);
    default: return 0;
    }
}

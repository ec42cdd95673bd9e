/* Struct sizes for the host bindings' load-time checks (lsw_abi.h). Host library only. */
#include "lsw_abi.h"

#include "fastsw.h"
#include "fastsw_batch.h"
#include "lsw_bank.h"
#include "lsw_clock.h"

size_t lsw_abi_size(int which)
{
    switch (which) {
    case LSW_ABI_SETTINGS: return sizeof(FastswSettings);
    case LSW_ABI_POINT: return sizeof(FastswPoint);
    case LSW_ABI_BATCH_OUT: return sizeof(FastswBatchOut);
    case LSW_ABI_BANK_WIRE: return sizeof(LswBankWire);
    case LSW_ABI_SYNC: return sizeof(LswSync);
    default: return 0;
    }
}

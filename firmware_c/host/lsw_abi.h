/**
 * @file lsw_abi.h
 * @brief Sizes of the structs the host bindings mirror (limbstream/kernel/_lib.py), so that a
 * binding whose copy of a struct drifted from the C declaration fails at load, not in a call.
 */
#ifndef LSW_ABI_H
#define LSW_ABI_H

#include <stddef.h>

/** Structs whose size the bindings check. */
typedef enum {
    LSW_ABI_SETTINGS = 0,  /**< FastswSettings */
    LSW_ABI_POINT = 1,     /**< FastswPoint */
    LSW_ABI_BATCH_OUT = 2, /**< FastswBatchOut */
    LSW_ABI_BANK_WIRE = 3, /**< LswBankWire */
    LSW_ABI_SYNC = 4,      /**< LswSync */
    LSW_ABI_GRID_SETTINGS = 5, /**< LswGridSettings */
    LSW_ABI_GRID_DEVICE = 6,   /**< LswGridDevice */
    LSW_ABI_SVR_TRACKER = 7,   /**< LswSvrTracker */
    LSW_ABI_SVR_ROUTE = 8,     /**< LswSvrRoute */
    LSW_ABI_SVR_SLOW = 9,      /**< LswSvrSlow */
    LSW_ABI_RAW_SAMPLE = 10,   /**< LswRawSample */
    LSW_ABI_IMU_SETTINGS = 11, /**< LswImuSettings */
    LSW_ABI_FUSE_ROWS = 12,    /**< LswFuseRows */
    LSW_ABI_ROOT_STATE = 13,   /**< LswRootState */
    LSW_ABI_ROOT_CONST = 14,   /**< LswRootConst */
} LswAbiStruct;

/** sizeof the struct ``which``; 0 for an unknown one. */
size_t lsw_abi_size(int which);

#endif

/* tc_errors.h - error codes of the fixed-point filter and the load-cell trigger.
 *
 * 0 is success. The filter/trigger use 1..99; the sensor drivers keep their
 * own codes in their headers (hx71x.h from 101, ads1220.h from 121), so one
 * number names its source. A sensor driver that fails during a probing move
 * passes its own code to tc_trigger_abort(), and the trigger reports it as is.
 * The numbers are part of the MCU/host interface: the host binding
 * (src/tapcell/mcu/trigger.py, TriggerError) mirrors them.
 */
#ifndef TAPCELL_TC_ERRORS_H
#define TAPCELL_TC_ERRORS_H

enum tc_error {
    TC_OK = 0,
    TC_ERR_FORCE_SAFETY = 1,     /* at arm: tare outside reference_tare_counts +- force limit;
                                    during the move: a raw sample outside that window or outside
                                    tare +- force limit (checked on every sample, no quarantine) */
    TC_ERR_DRIFT_SAFETY = 2,     /* during the move: two samples in a row outside tare +- drift limit */
    TC_ERR_WATCHDOG_TIMEOUT = 3, /* no sample for more than watchdog_periods sample periods */
    TC_ERR_FILTER_OVERFLOW = 4,  /* a filter value left its integer range (output saturated) */
    TC_ERR_SCALE_OVERFLOW = 5,   /* counts -> grams left int32 Q16.15 (beyond +-65536 g) */
    TC_ERR_BAD_CONFIG = 6,       /* a configuration value is out of its documented range */
    TC_ERR_STUCK_SENSOR = 7      /* stuck_samples raw samples in a row with one value: sensor stuck */
};

#endif

"""Defaults and ranges of the live correction and scoring: the node parameters, the core's
CorrectionParams, offline `correct` and the CLIs all take them from here. Ranges are inclusive."""

MASS_KG = 1.152                    # m2, thesis Table 7: 2.54 lbf/g (0.079 slug)
MASS_RANGE_KG = (1e-6, 1000.0)
WINDOW = 140                       # moving-average samples, thesis eq 25 (2.8 ms at 50 kHz)
WINDOW_RANGE = (1, 50_000)         # up to 1 s at 50 kHz
MAX_PENDING = 500                  # blocks a channel may wait for its partner before it is dropped
MAX_PENDING_RANGE = (1, 1_000_000)
VALIDATOR_MAX_PENDING = 20_000     # the corrected stream lags the force stream: 20 s of 1 ms blocks
NEW_RUN_GAP_S = 10.0               # a stamp jump forward by more than this starts a new run
NEW_RUN_GAP_RANGE_S = (0.001, 86_400.0)
ABORT_TIMEOUT_S = 10.0             # validator: a pull without data and without END for this long is aborted
ABORT_TIMEOUT_RANGE_S = (0.1, 3600.0)
LOADED_FRACTION = 0.1              # RMS window: stationary force above this share of its peak
LOADED_FRACTION_RANGE = (0.01, 0.99)
SHORT_EVENT_WINDOWS = 3.0          # an event narrower (FWHM) than this many moving-average windows is "short"
EVENT_BANDWIDTH_ENERGY = 0.95      # an event's bandwidth: the frequency below which this share of its energy lies
MA_HALF_POWER = 0.4429             # a W-point moving average passes half the power at MA_HALF_POWER * rate / W
# the corrected peak's uncertainty inputs (force_correction.core.peak_uncertainty.PeakInputs, k = 1): the ranges a
# node accepts; the values are the rig's (ft_cli.peak_inputs), 0 = not stated
PEAK_U_REL_RANGE = (0.0, 0.5)        # relative standard uncertainty of m2, the cell gain, the accel sensitivity
PEAK_U_DELAY_RANGE_S = (0.0, 1e-3)   # standard uncertainty of the accelerometer's lag

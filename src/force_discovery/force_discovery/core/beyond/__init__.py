"""Beyond the catalog: when the residual keeps structure no catalog cause explains, search a grammar of candidate
terms with sparse regression, fitted on the fitted pulls and scored on the held-out ones. ROS-free.

The grammar (its one home: force_tester_sim.core.extra_terms; per channel: grammar.py). A term is added to one
channel's model; the search forms the residual of SEARCHED: the stationary cell and the accelerometer on their own,
in the free phases (lanyard slack, T = 0: the stationary cell's model is 0, the accelerometer's the encoder's
acceleration), the moving cell over the analysis window after the named force-channel causes (with its free
phase before the load, series.before_samples: a zero drifting there with no load is no AC coupling), and the motor
current's force balance after the model of record (formed through the filter that makes the encoder's a3, so its
columns are the terms through that filter too, series.Through; the analog channels' lead fitted beside every term on
each pull, ChannelSeries.nuisance). The sensors come first: their product terms are taken out of
F_stat (and T) and a2 (series.sensor_corrected) before the moving cell and the current are searched, so a drifting
stationary cell is named on its own channel. A sensor's own terms are in the quantity it should read: the
accelerometer's a2 is the encoder's acceleration in its free phases, and a term in one sensor's signals alone found on
the moving cell (T^2, a2^3) is that sensor's own non-linearity (own.py); every pair of the grammar not identified is
listed with its reason (identify.py). A term is either a product of SIGNALS with integer powers (every
product of total degree <= 2 and every single signal cubed; written in the SIGNALS order, joined by ``*``, ``^k``
for k > 1), or a sinusoid ``sin`` at the frequency where the channel's residual spectrum peaks, optionally times a
signal (``v*sin``). A sinusoid's amplitude is one coefficient for the campaign; its phase is each pull's own (a mode
excited afresh in every pull), fitted per pull.

The search is forward selection over the library (selection.py; the column scales are the campaign's, so the
coefficients are comparable): at each step the term that lowers the fitted pulls' summed squared residual most
joins, all the chosen product terms are refitted together (least squares on the summed normal equations, one pull
at a time: each pull is kept as the Gram matrix of its library columns, normal_equations.ChannelStats, so memory
does not grow with the pulls), and the new term is kept only if it passes the held-out test of
significance.significance (held-out SSE -1 %, t >= 4 over the held-out pulls). At most MAX_TERMS per channel. Why
not PySINDy's sequentially thresholded least squares (STLSQ): measured on the same statistics
(benchmarks/bench_sparse.py, docs/discovery.md), it kept dozens of collinear companions with a threshold chosen on
the held-out error, and at the channel's band it spread a true term over its collinear neighbours until each fell
below it; forward selection with a held-out stopping rule, the catalog's own rule applied term by term, keeps them
out.

Each coefficient gets an uncertainty budget as the catalog's parameters do (budget.term_budget, as budget.honest):
the statistical part from a jackknife over the fitted pulls (Student's t, n-1), each systematic part the
coefficient's shift when one rig constant is one stated standard uncertainty off (m2 and the cell's gain on the
moving cell, each drive constant on the current: the residual's change kept as a Gram column per pull) or the
channel's sensor calibration (relative), and the 95 % interval budget.expanded. A term is named when it is
significant AND its contribution's rms on the held-out pulls, over that interval, lies above the channel's band
(practical significance: grammar.channel_band, from the rig's tolerances; on the motor current over the analysis
window, where bench_sweep sizes a term too).

The catalog keeps priority: on the motor current, the catalog's Coulomb friction (a step with the motion) is a
library column too; it stays named unless a single library term lowers the held-out residual by
PRIORITY_MARGIN more than it does (the same number of parameters: one). A term on the current is named only when
it beats the drive's causes in its place (the viscous damping, whose form is `v`, the Coulomb step, k_F and the
reflected mass; and the three drive constants together, by PRIORITY_MARGIN: Term's catalog_beat), and is fitted
with `v` beside it, so the damping's stated uncertainty is measured, not a systematic part of its budget; and
with the forms of the drive's k_F and reflected mass beside it,
whose stated lines give way to the data's where they separate the term from them (selection.search_channel). On
the moving cell each named force-model cause (priority.CAUSE_PARAMS) is checked by priority.cause_check with the
cause undone, on every campaign; a cause kept says what the library in its place left (BeyondResult.checked). A
cause a library term explains better is withheld: the report names the term and says the nearest catalog cause
does not fit (BeyondResult.demoted).

The modules, in the order a search runs:

- grammar.py          the library per channel, the channels searched, each channel's band
- series.py           per pull: each channel's residual and signals (ChannelSeries), the sensors' terms taken out
- spectrum.py         the spectrum pass on a few fitted pulls: the signals' scales, each channel's line (SearchSettings)
- normal_equations.py per pull: the library's normal equations per channel (ChannelStats, BeyondPart)
- selection.py        one channel's forward selection, its jackknife intervals (Model, Term, ChannelResult)
- own.py              a sensor's own non-linearity seen on the moving cell, read as the sensor's (own_reading); a
                      named term's near-tie group for the report (near_ties)
- identify.py         the pairs of the grammar a campaign cannot identify, and why (report: identifiability)
- priority.py         the catalog's priority on the moving cell (cause_check)
- search.py           every channel (search, BeyondResult)
- interpretation.py   what a term usually means, in plain words
- traces.py           the plots' before/after traces (TermTrace)
"""
from .grammar import COULOMB, SEARCHED, SENSORS, channel_band, channel_library, library, pairs
from .interpretation import interpretation
from .normal_equations import BeyondPart, ChannelStats, beyond_part
from .own import carrier, reading_factors
from .priority import CAUSE_PARAMS
from .search import BeyondResult, search
from .selection import NEAR_TIE, Term, near_tied, search_channel
from .series import ChannelSeries, before_samples, channel_series, decimation, sensor_corrected
from .spectrum import REFINE_PULLS, SearchSettings, settings_from, spectrum_part
from .traces import TermTrace, term_traces

__all__ = ['CAUSE_PARAMS', 'COULOMB', 'NEAR_TIE', 'REFINE_PULLS', 'SEARCHED', 'SENSORS', 'BeyondPart', 'BeyondResult',
           'ChannelSeries', 'ChannelStats', 'SearchSettings', 'Term', 'TermTrace', 'before_samples', 'beyond_part',
           'carrier', 'channel_band', 'channel_library', 'channel_series', 'decimation', 'interpretation', 'library',
           'near_tied', 'pairs', 'reading_factors', 'search', 'search_channel', 'sensor_corrected',
           'spectrum_part', 'settings_from', 'term_traces']

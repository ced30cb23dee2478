"""Friction: the motor current against the force balance of the model of record (the current channel); dry
friction is an offset F_c sign(v3). ROS-free.

Dry and viscous friction are fitted together when the campaign's pulls run at different speeds: each pull's
median force-balance residual while moving (minus at rest) is F_c + db v, v its median speed while moving, db the
viscous damping's departure from the rig YAML's b. A straight line through the pulls' (v, residual) gives F_c as
its intercept and db as its slope, so the drive's viscous damping is measured rather than taken from the rig YAML
with its wide stated uncertainty (viscous_separable says when the speeds allow it; otherwise F_c is the median
residual with the YAML's b).

The current's zero is the residual at rest BEFORE the carriage first moves (rest_level): after a stop a dry
contact holds whatever force the drive still applies, anywhere within +/- F_c (the velocity loop's integrator
keeps a current against it), so the rest after the pull is not the current's zero. On the independent generator's
tanh friction (seed 5102, F_c 218 N) the rest after the stop read -25 to -35 N and the friction came out 252 N;
the rest before the launch reads 0.01 N.

The drive is calibrated on the data, not taken from its datasheet (drive_fit): while the carriage moves, the
residual of a drive whose force per amp k_F is off by a fraction is that fraction of the drive force D = k_F i,
and one whose reflected mass is off is a multiple of a3; the drive force runs from the free phase (no load) to the
peak, so each pull's own least squares of its residual on [1, D, a3, v] measures both, and the pull's friction is
its residual with them taken out. The datasheet's 2 % on k_F leaves the friction's budget: the pulls' spread
carries the calibration's own noise instead. The fit regresses a residual on a drive force that contains it, so it
is checked against the reverse regression (the current on [1, F_move, a3, v], whose regressors are the cells' and
the encoder's): where the drive's balance holds sample by sample the two agree (own generator: within 0.1 %); where
it does not (the independent generator's drive: belt, encoder and controller dynamics in the transients) they part
by 5 to 200 % and neither is k_F. drive_calibration takes the calibration only where the two agree and the pulls
settle k_F better than the rig YAML states it; elsewhere the rows are the uncalibrated ones (calibrated_rows) and the
friction keeps the datasheet's lines. Each pull keeps its own fit (the estimate); the campaign's one k_F (pooled_rows)
is the other reading of the same calibration, and half the gap between the two frictions is a line (drive_lines).

Why they part there, from its data: per phase, the residual's regression on F_move while the cable is loaded (a few
ms) has slope -1 (the current does not follow the load within the load), and after the break F_move rings while the
current does not; what the current does not carry sits in F_move, a regressor of the reverse fit, which it
attenuates (s_reverse -3 to -236 %). No one lag between the current and the force makes them agree (a first-order
lag of 0.2-2 ms on either side moves them apart or swaps them); passing the current and F_move through a3's filter
(prep.like_a3) narrows the gap to 0.1-5 %. The balance of the impulses does hold: every column's mean over windows
of 20 ms (drive_fit's window_s, the impulse form) averages the rings and the lags out, and the forward and reverse
fits agree to 0.25 % or better on every pull of the four campaigns (median 0.02 %). impulse_form takes that form
where the sample form is refused and it is not (the own generator, whose sample form agrees, keeps it); its pulls' s
scatter by 0.5-1 % (tens of windows a pull), so its estimate is the campaign's one k_F (impulse_rows) and the window,
10 or 40 ms as well as 20, is a line of its own (drive_lines' form line)."""
from __future__ import annotations

import math
from typing import Iterable, Mapping, Optional, Sequence, Tuple

import numpy as np

from force_tester_common.core.events import median

from .prep import Pull

STILL_M_S = 1e-4     # |v3| below this: the carriage is at rest (no dry friction)
MOVING_M_S = 0.05    # v3 above this: moving forward (dry friction at its full value)
MIN_SPEED_SPREAD = 0.2   # the pulls' speeds must span this fraction of their mean to separate dry from viscous
MIN_REST_SAMPLES = 100   # rest samples before the first motion for the current's zero (else every rest sample)


def drive_force_balance(p: Pull, drive, fm: np.ndarray) -> np.ndarray:
    """The drive force the model of record needs for the pull's measured motion: m_c a3 + b v3 + F_move."""
    return drive.reflected_mass_kg * p.a3 + drive.viscous_damping_n_s_per_m * p.v3 + fm


def current_resid(p: Pull, rig) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    if p.current is None:
        return None
    d = rig.drive
    rho = p.current * d.force_per_amp_n_per_a - drive_force_balance(p, d, p.fm)
    moving = p.v3 > MOVING_M_S
    still = np.abs(p.v3) < STILL_M_S
    return rho, np.where(p.usable(), np.where(moving, 1.0, np.where(still, 0.0, np.nan)), np.nan)


def rest_level(rho: np.ndarray, sg: np.ndarray) -> float:
    """The current residual's zero (current_resid's (rho, sg)): its median at rest before the carriage first moves
    (module doc: after a stop, dry friction holds the drive's leftover force), or over every rest sample when the
    record has fewer than MIN_REST_SAMPLES of those."""
    still = sg == 0.0
    moving = np.flatnonzero(sg == 1.0)
    before = still[:moving[0]] if len(moving) else still
    if np.count_nonzero(before) >= MIN_REST_SAMPLES:
        return float(median(rho[:len(before)][before]))
    return float(median(rho[still]))


DRIVE_COLUMNS = 4          # drive_fit's regressors: 1, the drive force, a3, the speed about its median
MIN_DRIVE_SAMPLES = 200    # moving samples a pull needs for its own drive fit
IMPULSE_WINDOWS_S = (0.02, 0.01, 0.04)   # the impulse form's window: the nominal, then the two of its model-form line
MIN_WINDOWS = 8            # windows a pull needs for its impulse-form fit
SAMPLE_FORM = (0, 1, 3, 6)       # friction_row's columns of a drive form: moving, rest, s, s_reverse ...
IMPULSE_FORM = (8, 9, 10, 11)    # ... the impulse form's (the nominal window); then moving, rest, s at the other two
IMPULSE_ALTERNATIVES = ((12, 13, 14), (15, 16, 17))
IMPULSE_ROW = 18                 # friction_row's width


def moving_windows(mv: np.ndarray, n: int) -> np.ndarray:
    """(k, n) sample indices: every run of moving samples (mv) cut into whole windows of n samples."""
    idx = np.flatnonzero(mv)
    out = [r[:len(r) // n * n].reshape(-1, n) for r in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)]
    return np.concatenate(out) if out else np.zeros((0, n), int)


def drive_fit(p: Pull, rho: np.ndarray, sg: np.ndarray, force_per_amp: float,
              window_s: float = 0.0) -> Optional[np.ndarray]:
    """(s, e, w, s_reverse): the least squares of the pull's residual while moving (current_resid's rho where sg is
    1) on [1, D, a3, v3 - its median] (D = force_per_amp i, the drive force the current says): s the fraction of D
    the rig YAML's force per amp is off by (the true one is force_per_amp (1 - s)), e the reflected mass's departure
    (kg), w a viscous departure within the pull; and s_reverse the same fraction from the reverse regression, the
    current on [1, F_move, a3, v3 - its median] (module doc); None with fewer than MIN_DRIVE_SAMPLES moving
    samples or a rank-deficient fit. window_s > 0: the impulse form, every column the mean over windows of that
    length (moving_windows; at least MIN_WINDOWS of them): the balance of the impulses, which a lag or a ring
    between the current and the force shorter than the window does not break (module doc)."""
    mv = sg == 1.0
    if np.count_nonzero(mv) < MIN_DRIVE_SAMPLES:
        return None
    vm = median(p.v3[mv])
    if window_s > 0:
        w = moving_windows(mv, max(1, int(round(window_s / p.dt))))
        if len(w) < MIN_WINDOWS:
            return None

        def cols(x):
            return x[w].mean(axis=1)
    else:
        def cols(x):
            return x[mv]
    cur, y, fm = cols(p.current), cols(rho), cols(p.fm)
    X = np.column_stack([np.ones(len(y)), force_per_amp * cur, cols(p.a3), cols(p.v3) - vm])
    coef, _res, rank, _sv = np.linalg.lstsq(X, y, rcond=None)
    X[:, 1] = fm
    rev, _res, rank_r, _sv = np.linalg.lstsq(X, cur, rcond=None)
    if rank < DRIVE_COLUMNS or rank_r < DRIVE_COLUMNS or not rev[1] > 0:
        return None
    return np.r_[coef[1:], 1.0 - 1.0 / (rev[1] * force_per_amp)]


def drive_calibration(rows: Optional[np.ndarray], rig) -> Optional[Tuple[float, float]]:
    """(k_F, its standard uncertainty) in N/A: the drive's force per amp the fitted pulls' drive fits measure (their
    mean s, friction_row's column 3), its u the pulls' standard deviation over sqrt(n) and half the gap to the
    reverse regression's mean (column 6: module doc) in quadrature; when every pull has a fit and that u is below
    the rig YAML's own (the torque constant's and the pulley radius's). Else None: the data do not settle k_F
    better than its datasheet, and the friction keeps the stated lines (calibrated_rows)."""
    if rows is None or rows.shape[1] <= 7 or len(rows) < 3 or not np.all(np.isfinite(rows[:, [3, 6]])):
        return None
    d, u = rig.drive, rig.uncertainty
    stated = math.hypot(u.relative('drive.torque_constant_nm_per_a', d.torque_constant_nm_per_a),
                        u.relative('drive.pulley_radius_m', d.pulley_radius_m))
    s = rows[:, 3]
    gap = float(np.mean(s) - np.mean(rows[:, 6]))
    u_s = math.hypot(float(np.std(s, ddof=1)) / math.sqrt(len(s)), gap / 2.0)
    if not u_s < stated:
        return None
    kf = d.force_per_amp_n_per_a
    return kf * (1.0 - float(np.mean(s))), kf * u_s


def drive_line(rows: np.ndarray, u_rel: float) -> float:
    """The friction's line from the drive calibration's own uncertainty (u_rel: drive_calibration's u over its k_F):
    the fitted pulls' mean median drive force while moving (friction_row's column 7) times u_rel, what k_F that far
    off moves each pull's friction by."""
    return float(np.mean(np.abs(rows[:, 7]))) * u_rel


def drive_lines(rows: np.ndarray, drive: Tuple[float, float], raw: np.ndarray, rig,
                impulse: bool = False) -> Tuple[float, ...]:
    """(drive_line, the model line, the pooling line; with impulse, the form line): with the drive calibrated
    (drive: drive_calibration's (k_F, u)), its own u's effect; half the gap between the friction the calibrated rows
    give and the one the datasheet's drive gives (raw: calibrated_rows(rows, False)): two models of the drive that
    both fit the data, on the own generator 0.4-3 N, what the calibration's own spread does not show; and half the
    gap between the friction with each pull's own k_F (the estimate) and with the campaign's one k_F (pooled_rows):
    the pulls of one set agree on their k_F to 0.01 %, but a set's fit can part from the others' by 20-30 % of the
    k_F departure (own generator, --trials 4: the slowest set, 2.4 m/s), and the line through the sets' (speed,
    friction) carries that part times the set's drive force, extrapolated to v = 0 (there 0.7-4.5 N, 0.85-3.9 N off
    the truth). With impulse (the rows are impulse_rows', whose estimate is the campaign's one k_F: no pooling
    line), the RMS of the friction's departures at the impulse form's two other windows (IMPULSE_WINDOWS_S, each
    pooled too) from the nominal's: the window is a choice the data do not make. Each with its own viscous fit
    where the speeds allow one."""
    def stat(r):
        return friction_stat(r, viscous_separable(r, viscous_u(rig)))
    cal = calibrated_rows(rows, True)
    stats = [stat(r) for r in (cal, raw)]
    out = drive_line(rows, drive[1] / drive[0]), abs(stats[0] - stats[1]) / 2.0
    if not impulse:
        return (*out, abs(stats[0] - stat(pooled_rows(rows))) / 2.0)
    out = (*out, 0.0)   # the impulse form's rows are pooled already (impulse_rows)
    alts = []
    for cols in IMPULSE_ALTERNATIVES:
        ok = np.all(np.isfinite(rows[:, list(cols)]), axis=1)
        if np.count_nonzero(ok) >= 3:
            alt = np.array(cal[ok])
            alt[:, :2] = pooled(rows[ok][:, list(cols)], rows[ok, 7])[:, :2]
            alts.append(stat(alt) - stat(cal[ok]))
    return (*out, float(math.sqrt(np.mean(np.square(alts)))) if alts else 0.0)


def pooled(mrs: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """(moving, rest, s) rows with each pull's s replaced by their mean: the moving residual moves by (s - mean s) D
    (drive: each pull's median drive force while moving, friction_row's column 7)."""
    out = np.array(mrs, float)
    out[:, 0] = out[:, 0] + (out[:, 2] - np.mean(out[:, 2])) * drive
    return out


def impulse_rows(rows) -> np.ndarray:
    """The friction_row()s of a campaign's fitted pulls in the drive's impulse form: its moving, rest, s and
    s_reverse (IMPULSE_FORM) in the sample form's places (SAMPLE_FORM), where calibrated_rows, drive_calibration
    and pooled_rows read them, and the moving residual with the campaign's one k_F (the pulls' mean s, pooled): a
    pull's impulse fit has tens of windows, so its own s scatters by 0.5-1 % (independent generator) about the
    rig's one k_F, a scatter drive_calibration's u carries."""
    out = np.array(rows, float)
    out[:, list(SAMPLE_FORM)] = out[:, list(IMPULSE_FORM)]
    out[:, 0] = pooled(out[:, [0, 1, 3]], out[:, 7])[:, 0]
    return out


def impulse_variants(rows_v: Sequence[Mapping[str, tuple]]) -> list:
    """The fitted pulls' friction_variants() ({variant: friction_row()} per pull) in the impulse form: each
    variant's rows over the campaign through impulse_rows."""
    names = list(rows_v[0])
    per = {n: impulse_rows(np.array([v[n] for v in rows_v], float)) for n in names}
    return [{n: per[n][k] for n in names} for k in range(len(rows_v))]


def impulse_form(rows: Optional[np.ndarray], rig) -> bool:
    """Whether the data support the drive's impulse form and not its sample form: the sample-by-sample balance does
    not calibrate the drive (drive_calibration None: its forward and reverse regressions part) and the balance of
    the window means does (module doc)."""
    return (rows is not None and rows.shape[1] >= IMPULSE_ROW and drive_calibration(rows, rig) is None
            and drive_calibration(impulse_rows(rows), rig) is not None)


def pooled_rows(rows: np.ndarray) -> np.ndarray:
    """The calibrated rows (calibrated_rows(rows, True)) with each pull's own force-per-amp fraction s (column 3)
    replaced by the fitted pulls' mean, drive_calibration's one k_F for the campaign: each pull's moving residual
    moves by (s - mean s) D (D its median drive force while moving, column 7; the median of the shifted residual
    taken as the shifted median, as drive_line takes it)."""
    out = np.array(calibrated_rows(rows, True), float)
    out[:, 0] = out[:, 0] + (rows[:, 3] - np.mean(rows[:, 3])) * rows[:, 7]
    return out


def calibrated_rows(rows: np.ndarray, calibrated: bool) -> np.ndarray:
    """The friction_row()s' (moving, rest, speed) columns: the drive-calibrated ones, or with calibrated False the
    uncalibrated ones (columns 4 and 5); rows of three columns as they are."""
    rows = np.asarray(rows, float)
    if rows.shape[1] <= 3:
        return rows
    return rows[:, :3] if calibrated else rows[:, [4, 5, 2]]


def viscous_fit(rows: np.ndarray) -> Optional[Tuple[float, float, float, float]]:
    """(F_c, db, the standard error of db, the standard error of F_c) of the least-squares line through the pulls'
    (speed, moving minus still residual) (rows: friction_row()s); None when the speeds do not span
    MIN_SPEED_SPREAD of their mean or there are fewer than 3 pulls."""
    rows = np.asarray(rows, float)
    if rows.ndim != 2 or rows.shape[1] < 3 or len(rows) < 3:
        return None
    v, y = rows[:, 2], rows[:, 0] - rows[:, 1]
    vbar = float(np.mean(v))
    sxx = float(np.sum((v - vbar) ** 2))
    if not (np.ptp(v) >= MIN_SPEED_SPREAD * abs(vbar) and sxx > 0):
        return None
    db = float(np.sum((v - vbar) * (y - y.mean())) / sxx)
    fc = float(y.mean() - db * vbar)
    s2 = float(np.sum((y - fc - db * v) ** 2)) / (len(v) - 2)
    return fc, db, math.sqrt(s2 / sxx), math.sqrt(s2 * (1.0 / len(v) + vbar * vbar / sxx))


def joint_ci(rows: np.ndarray, confidence: float) -> Tuple[float, float]:
    """The confidence interval of viscous_fit's F_c: Student's t with n - 2 degrees of freedom on its standard
    error (the textbook interval of a line's intercept; a bootstrap over so few pulls is too narrow)."""
    from scipy.stats import t
    fc, _db, _se_db, se = viscous_fit(rows)
    h = float(t.ppf(0.5 + confidence / 2, len(rows) - 2)) * se
    return fc - h, fc + h


def viscous_separable(rows: Optional[np.ndarray], u_b: float) -> bool:
    """Whether the pulls' speeds measure the viscous damping better than the rig YAML states it (u_b: its
    standard uncertainty): then friction_stat(rows, joint=True)."""
    if rows is None:
        return False
    fit = viscous_fit(rows)
    return fit is not None and fit[2] < u_b


def viscous_u(rig) -> float:
    """The standard uncertainty of the drive's viscous damping b (motor + actuator) the rig YAML states."""
    u = rig.uncertainty
    return math.hypot(u.u('drive.viscous_damping_motor_n_s_per_m'), u.u('drive.viscous_damping_actuator_n_s_per_m'))


def friction_stat(rows: np.ndarray, joint: bool = False) -> float:
    """The friction force from the friction_row()s: joint, the intercept of viscous_fit (when the rows allow one,
    as a bootstrap resample may not); else the median residual while moving minus at rest."""
    if joint:
        fit = viscous_fit(rows)
        if fit is not None:
            return fit[0]
    return float(np.median(rows[:, 0]) - np.median(rows[:, 1]))


def viscous_departure(rows: Optional[np.ndarray], joint: bool) -> float:
    """db, the viscous damping's departure from the rig YAML's the rows measure (0 when not joint)."""
    fit = viscous_fit(rows) if (joint and rows is not None) else None
    return 0.0 if fit is None else fit[1]


def friction_row(p: Pull, rig) -> Optional[tuple]:
    """(moving, rest, speed, s, moving_raw, rest_raw, s_reverse, drive, then the impulse form's moving, rest, s,
    s_reverse, then moving, rest, s at each of its two other windows): the pull's median force-balance residual while
    moving and at rest (rest_level) with its own drive fit taken out (drive_fit: the residual less s D + e a3, and
    while moving less w (v3 - its median)), its median speed while moving, the fit's s (nan without one: then the
    first two are the raw ones), the two medians of the raw residual (calibrated_rows picks), the reverse
    regression's s (drive_calibration checks s against it) and the median drive force D while moving (what a
    fraction off k_F moves the friction by: drive_line); then the same with the impulse form's fit
    (IMPULSE_WINDOWS_S; nan without one; impulse_rows puts them in place) and the moving, rest and s of its fits at
    the two other windows (drive_lines' form line). None without a current channel."""
    cr = current_resid(p, rig)
    if cr is None:
        return None
    rho, sg = cr
    mv = sg == 1.0
    v = median(p.v3[mv])
    raw = median(rho[mv]), rest_level(rho, sg)
    kf = rig.drive.force_per_amp_n_per_a
    drive = median(kf * p.current[mv])

    def taken_out(fit):
        if fit is None:
            return math.nan, math.nan
        s, e, w, _s_reverse = fit
        cal = rho - s * kf * p.current - e * p.a3
        return median(cal[mv] - w * (p.v3[mv] - v)), rest_level(cal, sg)

    fits = [drive_fit(p, rho, sg, kf, window) for window in IMPULSE_WINDOWS_S]
    nominal = (math.nan, math.nan) if fits[0] is None else (float(fits[0][0]), float(fits[0][3]))
    impulse = (*taken_out(fits[0]), *nominal)
    for f in fits[1:]:
        impulse += (*taken_out(f), math.nan if f is None else float(f[0]))
    fit = drive_fit(p, rho, sg, kf)
    if fit is None:
        return (*raw, v, math.nan, *raw, math.nan, drive, *impulse)
    return (*taken_out(fit), v, float(fit[0]), *raw, float(fit[3]), drive, *impulse)


def friction_rows(rows: Iterable[Optional[tuple]]) -> Optional[np.ndarray]:
    """The friction_row()s as an array, None when a pull had no current channel."""
    out = []
    for r in rows:
        if r is None:
            return None
        out.append(r)
    return np.array(out)


def friction_sse(p: Pull, rig, fc: float, db: float = 0.0) -> float:
    """The pull's squared current residual (A^2, clipped at 3 x its 95th percentile) with dry friction fc and the
    viscous damping db off the rig YAML's."""
    rho, sg = current_resid(p, rig)
    rho = rho - db * p.v3
    ok = ~np.isnan(sg)
    r = rho[ok] - fc * sg[ok]
    r = r - rest_level(rho, sg)
    r = np.clip(r, -np.percentile(np.abs(r), 95) * 3 - 1e-9, np.percentile(np.abs(r), 95) * 3 + 1e-9)
    return float(np.sum((r / rig.drive.force_per_amp_n_per_a) ** 2))   # in A^2

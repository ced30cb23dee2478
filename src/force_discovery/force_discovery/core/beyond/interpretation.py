"""What a term found on a channel usually means, in plain words (report.json's `interpretation`). ROS-free."""
from __future__ import annotations

from typing import Optional

from force_tester_sim.core.extra_terms import SIN, parse_term

INTERPRETATION = {
    ('force_moving', 'F_move^2'): 'a non-linear moving cell: its sensitivity changes with load',
    ('force_moving', 'F_move^3'): 'a non-linear moving cell: its sensitivity changes with load',
    ('force_moving', 'T^2'): 'a non-linear moving cell (seen against the tension): its sensitivity changes with load',
    ('force_moving', 'F_stat^2'): 'a non-linear cell (seen against the stationary cell)',
    ('force_moving', 't'): "the moving cell's zero drifts through the record (thermal drift, charge-amplifier "
                           'leakage)',
    ('force_moving', 'v'): 'a velocity-dependent force on the moving cell: cable drag or a viscous coupling',
    ('force_moving', 'x'): 'a force that grows along the travel on the moving cell: a cable or hose pulling on it',
    ('force_stationary', 't'): "the stationary cell's zero drifts through the record (thermal drift, "
                               'charge-amplifier leakage); the tension T it gives drifts with it',
    ('force_stationary', 'x'): 'the stationary cell reads a force that follows the carriage: crosstalk or a '
                               'cable pulling on the fixture',
    ('force_stationary', 'F_stat^2'): 'a non-linear stationary cell: its sensitivity changes with load (seen under '
                                      "load, against the moving side's tension)",
    ('force_stationary', 'F_stat^3'): 'a non-linear stationary cell: its sensitivity changes with load (seen under '
                                      "load, against the moving side's tension)",
    ('accel_axial', 'a2'): "the accelerometer's sensitivity is off against the encoder's acceleration (its "
                           'calibration)',
    ('accel_axial', 'a2^2'): 'a non-linear accelerometer: its sensitivity changes with the acceleration (even: it '
                             'reads a push and a pull of one size differently)',
    ('accel_axial', 'a2^3'): 'a non-linear accelerometer: its sensitivity changes with the acceleration (odd: it '
                             'compresses or stiffens at large accelerations)',
    ('accel_axial', 't'): "the accelerometer's zero drifts through the record (thermal drift, a conditioner's "
                          'offset creeping)',
    ('accel_axial', 'v'): 'the accelerometer reads a share of the speed: a cable whipping or a mounting that '
                          'flexes with the motion',
    ('motor_current', 'v^2'): 'aerodynamic drag on the carriage',
    ('motor_current', 'v'): "viscous friction beyond the drive model's (lubricated guides, a damper)",
    ('motor_current', 'x'): 'a force that grows along the travel: a binding rail or a cable acting as a spring',
    ('motor_current', 'v*x'): 'a friction that grows along the travel and acts only while sliding (a binding or '
                              'misaligned rail): the grammar has no while-sliding factor, and x times the speed, 0 at '
                              'rest, stands for it (its coefficient times the speed is the friction per metre)',
    ('motor_current', 't'): "the current sensor's zero drifts through the record",
    ('motor_current', 'F_move'): "the drive's force constant or the moving cell's gain is off (force per amp)",
    ('motor_current', 'a2'): 'a mass the drive moves that the model of record does not have',
}
NO_READING = 'no usual physical reading: a term the catalog has no entry for; look at where it acts (report.md)'
SIN_INTERPRETATION = {'': 'a structural (frame) mode ringing at {f:.1f} Hz',
                      'v': 'a structural (frame) mode at {f:.1f} Hz excited by the carriage: it grows with speed',
                      'F_move': 'a structural mode at {f:.1f} Hz excited by the load'}


def interpretation(channel: str, term: str, f_hz: Optional[float] = None) -> str:
    p = parse_term(term)
    if SIN in p:
        factor = next((s for s in p if s != SIN), '')
        return SIN_INTERPRETATION.get(factor, 'a structural mode at {f:.1f} Hz, modulated by ' + factor).format(
            f=f_hz or 0.0)
    if (channel, term) in INTERPRETATION:
        return INTERPRETATION[(channel, term)]
    if channel == 'force_moving' and set(p) <= {'F_move', 'F_stat', 'T'} and sum(p.values()) > 1:
        return INTERPRETATION[('force_moving', 'F_move^2')]
    return NO_READING


"""The catalog's priority on the moving cell: a named force-model cause stays named only when its model explains the
structure no worse than library terms with the same number of parameters (cause_check). ROS-free."""
from __future__ import annotations

from typing import NamedTuple, Optional, Sequence

from force_tester_sim.core.extra_terms import SIN

from .grammar import GAIN, MASS
from .normal_equations import ChannelStats
from .selection import PRIORITY_MARGIN, Model, Term, search_channel, sse
from .spectrum import SearchSettings

# parameters of each force-model cause the check weighs against library terms (the hum: amplitude and phase)
CAUSE_PARAMS = {GAIN: 1, MASS: 1, 'accel_delay': 1, 'ac_coupling': 1, 'mains_hum': 2}


class CauseCheck(NamedTuple):
    """cause_check's answer."""

    demoted: Optional[str]          # why the named cause does not fit, or None: it keeps priority
    terms: Sequence[Term]           # the terms the library finds with the cause undone
    beat: Optional[dict] = None     # a cause that keeps priority: the library's best in its place, and by how much


def undone(st: ChannelStats, cause: str) -> ChannelStats:
    """A pull's moving-cell statistics with a named cause undone: y0 = y + c (c: its contribution,
    series.channel_series)."""
    c = st.causes[cause]
    return st._replace(xy=st.xy + c.cx, yy=st.yy + 2 * c.cy + c.cc)


def cause_check(fit: Sequence[ChannelStats], held: Sequence[ChannelStats], model: Model, settings: SearchSettings, rig,
                cause: str) -> CauseCheck:
    """Whether the named force-model cause keeps priority: the library is searched again on the moving cell's
    residual with the cause undone, and if it does as well on the held-out pulls with no more parameters
    (CAUSE_PARAMS: the cause's), the cause is withheld."""
    n_prod = sum(1 for nm in fit[0].names if not nm.endswith(SIN))
    fit0, held0 = [undone(st, cause) for st in fit], [undone(st, cause) for st in held]
    found0, _, model0, _ = search_channel('force_moving', fit0, held0, settings, rig, False)
    n_cause = CAUSE_PARAMS.get(cause, 1)
    k_cat = len(model.prod) + (model.sin is not None) + n_cause
    k_lib = len(model0.prod) + (model0.sin is not None)
    sse_cat = sum(sse(st, model, n_prod) for st in held)
    sse_lib = sum(sse(st, model0, n_prod) for st in held0)
    what = ', '.join(t.term for t in found0) or 'no term at all'
    if k_lib <= k_cat and sse_lib <= sse_cat * (1.0 + (PRIORITY_MARGIN if k_lib < k_cat else 0.0)):
        return CauseCheck(
            f'without {cause} the library explains the moving cell with {k_lib} parameter(s) ({what}) as well '
            f'as the model with it does with {k_cat} ({n_cause} of them its own; held-out SSE {sse_lib:.4g} '
            f'against {sse_cat:.4g}): the nearest catalog cause does not fit', found0)
    return CauseCheck(None, found0, {'library_instead': what, 'library_parameters': k_lib, 'model_parameters': k_cat,
                                     'held_out_sse_library': sse_lib, 'held_out_sse_with_cause': sse_cat,
                                     'held_out_margin': (sse_lib - sse_cat) / sse_lib if sse_lib > 0 else 0.0})

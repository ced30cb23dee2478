"""What the sim node runs: which pulls, in which blocks, on which sample clock (ROS-free)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

from force_tester_common.core.blocks import BLOCK_SAMPLES, BLOCK_SAMPLES_RANGE

from .campaign import truth_pull_specs
from .errors import SimError
from .params import RigParams, load_rig
from .pull import make_pull_specs


@dataclass(frozen=True)
class SimConfig:
    """The sim node's parameters, validated. ``rate`` is the pace: 1.0 real time, 10.0 ten times faster."""
    test_sets: tuple = (1, 2, 3, 4, 5)
    pulls_per_set: int = 1
    seed: int = 0
    block_size: int = BLOCK_SAMPLES
    rate: float = 1.0
    rig_file: str = ''
    noise: bool = True
    coupons: str = 'rated'
    drive: bool = True

    COUPONS = ('rated', 'measured')

    def __post_init__(self):
        if not self.test_sets:
            raise SimError('test_sets is empty; expected one or more of 1, 2, 3, 4, 5')
        if not 1 <= self.pulls_per_set <= 1000:
            raise SimError(f'pulls_per_set {self.pulls_per_set} is out of range; expected an integer in [1, 1000]')
        lo, hi = BLOCK_SAMPLES_RANGE
        if not lo <= self.block_size <= hi:
            raise SimError(f'block_size {self.block_size} is out of range; expected an integer in [{lo}, {hi}] samples')
        if not 0.01 <= self.rate <= 1000.0:
            raise SimError(f'rate {self.rate} is out of range; expected a real-time factor in [0.01, 1000]')
        if self.coupons not in self.COUPONS:
            raise SimError(f"coupons {self.coupons!r} is unknown; expected one of {', '.join(self.COUPONS)}")
        if self.seed < 0:
            raise SimError(f'seed {self.seed} is negative; expected an integer >= 0')
        rig = self.rig()
        for s in self.test_sets:
            rig.test_set(int(s))

    def rig(self) -> RigParams:
        return load_rig(self.rig_file or None)

    def pull_specs(self, rig: RigParams, test_set: int, seed: int):
        """'rated': coupons break at their rating on an elastic lanyard (nominal scatter);
        'measured': at the set's measured level (thesis Table 7), yielding first, as in the reference campaign."""
        if self.coupons == 'measured':
            return truth_pull_specs(rig, test_set, self.pulls_per_set, seed)
        return make_pull_specs(rig, test_set, self.pulls_per_set, seed)


def block_bounds(n_samples: int, block_size: int) -> Iterator[tuple]:
    """(start, stop) of each block of a record; the last block may be shorter."""
    for start in range(0, n_samples, block_size):
        yield start, min(start + block_size, n_samples)

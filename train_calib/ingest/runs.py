"""Run segmentation: ``run_id`` and the time since the previous measurement of the run. Stamps in ns."""

from __future__ import annotations

from .config import Settings
from .records import NS


class RunSegmenter:
    """A new run at a departure after a standstill of at least ``min_standstill`` (once the run has moved), after
    a gap in the measurements longer than ``run_gap``, back in the track direction after reversing, and on a new
    time base (clock reset). ``run_id`` starts at 0 and outlives the time bases."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.run_id = 0
        self._start_time_base()

    def _start_time_base(self) -> None:
        self.run_moved = False
        self.standstill_since: int | None = None
        self.last_meas_t: int | None = None
        self.new_run_next = False  # back in the track direction: the next measurement starts a run

    def new_time_base(self) -> None:
        """A clock reset: a new run when this time base had measurements."""
        if self.last_meas_t is not None:
            self.run_id += 1
        self._start_time_base()

    def forward_again(self) -> None:
        """The fixes move in the track direction again after reversing."""
        self.new_run_next = True

    def segment(self, t_ns: int, v: float) -> tuple[int, float]:
        """Run id and dt (s; 0 for the first of a run) of a measurement at t with speed v (m/s)."""
        cfg = self.settings.config
        new_run = False
        if self.last_meas_t is not None and (t_ns - self.last_meas_t) / NS > cfg.run_gap:
            new_run = self.run_moved
            self.standstill_since = None
        if self.new_run_next:  # back in the track direction after reversing
            new_run = self.last_meas_t is not None
            self.new_run_next = False
        if v <= cfg.standstill_speed:
            if self.standstill_since is None:
                self.standstill_since = t_ns
        else:
            if (
                self.standstill_since is not None
                and self.run_moved
                and (t_ns - self.standstill_since) / NS >= cfg.min_standstill
            ):
                new_run = True
            self.standstill_since = None
        if new_run:
            self.run_id += 1
            self.run_moved = False
        dt = 0.0 if (new_run or self.last_meas_t is None) else (t_ns - self.last_meas_t) / NS
        if v > cfg.standstill_speed:
            self.run_moved = True
        self.last_meas_t = t_ns
        return self.run_id, dt

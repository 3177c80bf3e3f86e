"""Configuration of the sliding-window calibration (De Martinis & Corman 2019), one frozen ParamSet.

Bounds are per unit of effective mass (N/kg, as r0, r1, r2 everywhere in train_calib), so one file
serves every train; the force-unit bounds on A, B, C are these times gamma * m of the train.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..params import ParamSet, param

GOF_KINDS = ("sae", "rmse")
"""Goodness-of-fit functions; the index is the WindowResistance.GOF_* constant."""

DIFFERENCE_SCHEMES = ("forward", "midpoint", "trapezoid")


@dataclass(frozen=True)
class WindowConfig(ParamSet):
    """Sliding-window calibration of A, B, C from traction power (defaults: the paper's or measured, docs/window.md)."""

    window_length: float = param(
        60.0,
        "length of the sliding window; the fit uses the difference steps ending in it",
        unit="s",
        low=2.0,
        high=3600.0,
    )
    gof: str = param("rmse", "goodness of fit: sae (linear programme) or rmse (least squares)", choices=GOF_KINDS)
    difference_scheme: str = param(
        "forward",
        "forward: their eq. 4 (forces at v_k, acceleration (v_k+1 - v_k)/dt); midpoint: resistance and track force"
        " averaged over the step's ends, tractive force of v_k held; trapezoid: every force averaged",
        choices=DIFFERENCE_SCHEMES,
    )
    min_speed: float = param(
        2.0, "samples slower than this give no tractive force (F = eta P / v) and are left out", unit="m/s", low=0.1
    )
    max_gap: float = param(
        5.0,
        "a longer gap between consecutive samples starts a new window (no difference across it)",
        unit="s",
        low=0.0,
        low_open=True,
    )
    r0_bounds: tuple[float, ...] = param((0.0, 0.05), "bounds on r0 = A / (gamma m)", unit="N/kg", low=0.0, high=1.0)
    r1_bounds: tuple[float, ...] = param(
        (0.0, 0.005), "bounds on r1 = B / (gamma m)", unit="N/(kg m/s)", low=0.0, high=0.1
    )
    r2_bounds: tuple[float, ...] = param(
        (0.0, 0.0005), "bounds on r2 = C / (gamma m) (open air)", unit="N/(kg (m/s)^2)", low=0.0, high=0.01
    )
    adhesion_constraint: bool = param(
        True, "their eq. 6: implied tractive effort <= Curtius-Kniffler adhesion limit of the driven axles"
    )
    traction_constraint: bool = param(
        True, "their eq. 7: implied tractive effort <= maximum tractive effort/power envelope of the train file"
    )
    constraint_sigma: float = param(
        2.0,
        "eq. 6/7 are applied with a margin of this many standard deviations of the measured acceleration (v_variance)",
        low=0.0,
        high=10.0,
    )
    exclude_braking: bool = param(
        True,
        "leave braking steps out of the fit: the mechanical brake share of the effort is not measured",
    )
    min_samples: int = param(8, "fewer usable difference steps make the window ill-posed", low=3, high=100000)
    min_speed_span: float = param(
        1.0, "a smaller max - min speed in the window makes it ill-posed (near-constant speed)", unit="m/s", low=0.0
    )
    max_condition: float = param(
        1000.0,
        "a larger condition number of the column-scaled design [1, v, v^2] makes the window ill-posed",
        low=1.0,
        low_open=False,
    )
    reference_speeds_kmh: tuple[float, ...] = param(
        (40.0, 80.0, 120.0),
        "speeds at which the fitted resistance must be determined",
        unit="km/h",
        low=0.0,
        high=600.0,
    )
    max_relative_error: float = param(
        0.5,
        "a larger standard error of r(v) at a reference speed, relative to the train file's r(v), makes the window"
        " ill-posed (noise, not resistance)",
        low=0.0,
        low_open=True,
    )
    regime_source: str = param(
        "regime_topic",
        "regime of each sample: regime_topic (the caller's, /train_calib/regime from regime_node) or power (their"
        " Section 5.1, from the measured force and acceleration; also used for samples without a given regime)",
        choices=("regime_topic", "power"),
    )
    max_regime_wait: int = param(
        30,
        "node: measurements held waiting for their /train_calib/regime; older ones use the regime from power",
        low=0,
        high=100000,
    )
    effort_tolerance: float = param(
        0.025, "regime from power when none is given: |F|/(gamma m) within this is coasting", unit="N/kg", low=0.0
    )
    cruise_tolerance: float = param(
        0.04,
        "regime from power: |a| within this with effort applied is cruising (De Martinis 5.1)",
        unit="m/s^2",
        low=0.0,
    )

    def validate(self, source: str = "parameters", prefix: str = "") -> None:
        from ..errors import ConfigError

        for name in ("r0_bounds", "r1_bounds", "r2_bounds"):
            bounds = getattr(self, name)
            if len(bounds) != 2 or not bounds[0] <= bounds[1]:
                raise ConfigError(
                    source, f"{prefix}{name}", f"expected [low, high] with low <= high, found {list(bounds)}"
                )

    @property
    def gof_kind(self) -> int:
        """WindowResistance.GOF_SAE (0) or GOF_RMSE (1)."""
        return GOF_KINDS.index(self.gof)

    @property
    def specific_bounds(self) -> tuple[tuple[float, float], ...]:
        """((r0_lo, r0_hi), (r1_lo, r1_hi), (r2_lo, r2_hi)) in N/kg units."""
        return tuple((float(b[0]), float(b[1])) for b in (self.r0_bounds, self.r1_bounds, self.r2_bounds))

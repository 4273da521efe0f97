"""Closed-loop position steps of the PLPA (seed 000, section 4, Fig. 15).

A step run logs the carriage position ``x`` and its reference ``x_ref``. Every jump of ``x_ref``
starts a step that lasts until the next jump (or the end of the run). Per step:

* overshoot: largest excursion beyond the new reference, in the direction of the step, in % of
  the step;
* settling time: from the jump to the last instant the error is outside the 2 % band (NaN when
  the error leaves the band during the last 10 % of the step: not shown to have settled);
* rise time: from the first crossing of 10 % of the step to the first crossing of 90 %;
* steady-state error: new reference minus the mean position over the last 10 % of the step,
  signed in the direction of the step (positive: short of the reference, negative: beyond it).
  Averaging does not take a quantised sensor's resolution out of it: a loop closed on an encoder
  holds the carriage anywhere within the count it reads, so each step also reports the position
  record's resolution (``position_resolution_mm``), which a reader of a mean over steps adds to its
  spread as a Type B standard uncertainty (resolution / sqrt(12), GUM F.2.2.1).

Crossing instants are interpolated linearly between samples. The position is first smoothed by
a zero-phase low-pass filter well above the loop's bandwidth, so that sensor noise does not move
the last exit from the 2 % band.

What the sensors allow (:mod:`analyses.quality`): a jump of ``x_ref`` is a step when it exceeds
one count of the reference's resolution and ``N_SIGMA`` noise sigmas (never a constant length),
taken between the reference's settled levels (a ramp is one step from where it starts);
a step smaller than ``N_SIGMA`` times the position sensor's floor gives no metrics, and one
whose 2 % band is finer than that floor gives no overshoot or settling time (``note`` says
which); a step that has not settled by the end of the record has no settling time and a note.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from analyses.numerics_iir import butter_lowpass_sos, sosfiltfilt2
from analyses.quality import Sensor, describe_sensor, setpoint_jumps, setpoint_thresholds, settle_points

__all__ = ["find_steps", "step_metrics", "step_response_metrics", "plot_step_errors", "N_SIGMA"]

#: Detection margin: a reference jump must exceed this many noise sigmas of the reference, and a
#: step must be this many times the position sensor's floor to be measured. [-]
N_SIGMA = 5.0


def find_steps(t, x_ref, min_step: float | None = None, min_duration_s: float = 0.0,
               sensor: Sensor | None = None, min_points: int = 3) -> list[tuple[int, int, float, float]]:
    """Jumps of the reference.

    Parameters
    ----------
    t : array_like
        Time. [s]
    x_ref : array_like
        Reference. [m]
    min_step : float, optional
        Smallest jump that counts as a step; default from the reference's sensor
        (:func:`analyses.quality.setpoint_thresholds`: one count of its resolution, ``N_SIGMA``
        noise sigmas). [m]
    min_duration_s : float
        Shortest step kept (a plateau shorter than this is not a step). [s]
    sensor : Sensor, optional
        Resolution and noise of ``x_ref`` (run metadata); estimated from it when absent.
    min_points : int
        A plateau shorter than this joins the next one (a ramped reference is one step).

    Returns
    -------
    list of (i_start, i_end, ref_before, ref_after)
        ``i_start`` is the first sample at the new reference, ``i_end`` one past the last sample
        of the step.
    """
    t = np.asarray(t, float)
    r = np.asarray(x_ref, float)
    if len(r) < 2:
        return []
    settle, noise = min_points, 0.0
    if min_step is None:
        sensor = sensor if sensor is not None else describe_sensor(r)
        jump, level = setpoint_thresholds(r, sensor, N_SIGMA)
        settle, noise = settle_points(sensor, min_points), sensor.noise
    else:
        jump = level = float(min_step)
    jumps = setpoint_jumps(r, jump, level, min_points, settle_points=settle, noise=noise)
    out = []
    bounds = list(jumps) + [len(r)]
    for j, i0 in enumerate(jumps):
        i1 = bounds[j + 1]
        before = float(np.median(r[(jumps[j - 1] if j else 0):i0]))
        after = float(np.median(r[i0:i1]))
        if abs(after - before) <= level or t[i1 - 1] - t[i0] < min_duration_s:
            continue
        out.append((int(i0), int(i1), float(before), after))
    return out


def _crossing(t, y, level, start=0):
    """First time at or after index ``start`` when ``y`` reaches ``level`` from below (interpolated)."""
    above = np.flatnonzero(y[start:] >= level)
    if len(above) == 0:
        return float("nan")
    i = start + int(above[0])
    if i == 0 or y[i - 1] >= level:
        return float(t[i])
    f = (level - y[i - 1]) / (y[i] - y[i - 1])
    return float(t[i - 1] + f * (t[i] - t[i - 1]))


@dataclass
class StepMetrics:
    """Metrics of one step (NaN when not defined)."""

    t_step_s: float
    step_mm: float
    overshoot_pct: float
    settling_time_s: float
    rise_time_s: float
    steady_state_error_mm: float
    settled: bool
    note: str | None = None


def step_metrics(t, x, t_step: float, ref_before: float, ref_after: float, band: float = 0.02,
                 x_before: float | None = None) -> StepMetrics:
    """Overshoot, 2 % settling time, 10-90 % rise time and steady-state error of one step.

    Parameters
    ----------
    t : array_like
        Time from the jump on (``t[0]`` may equal ``t_step``). [s]
    x : array_like
        Position over the step. [m]
    t_step : float
        Time of the jump. [s]
    ref_before, ref_after : float
        Reference before and after the jump. [m]
    band : float
        Settling band, fraction of the step. [-]
    x_before : float, optional
        Position when the step starts (default ``ref_before``): the 10 % and 90 % levels are
        measured from the reference, as in Fig. 15 (error in % of the step).

    Returns
    -------
    StepMetrics
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    step = ref_after - ref_before
    nan = float("nan")
    if len(t) < 3 or step == 0:
        return StepMetrics(t_step, step * 1e3, nan, nan, nan, nan, False)
    s = np.sign(step)
    base = ref_before if x_before is None else x_before
    y = s * (x - base) / abs(step)            # 0 at the start, 1 at the new reference
    target = s * (ref_after - base) / abs(step)
    overshoot = max(0.0, float(np.max(y) - target)) * 100.0
    t10 = _crossing(t, y, 0.1 * target)
    t90 = _crossing(t, y, 0.9 * target, start=max(0, int(np.searchsorted(t, t10))) if np.isfinite(t10) else 0)
    rise = t90 - t10
    err = np.abs(y - target)
    outside = np.flatnonzero(err > band)
    n_tail = max(3, len(t) // 10)
    settled = len(outside) == 0 or outside[-1] < len(t) - n_tail
    if len(outside) == 0:
        settling = max(0.0, float(t[0] - t_step))
    elif not settled:  # still outside the band in the last 10 % of the step: not settled
        settling = nan
    else:
        i = int(outside[-1])
        # interpolate the instant the error re-enters the band
        e0, e1 = err[i] - band, err[i + 1] - band
        f = e0 / (e0 - e1) if e0 != e1 else 0.0
        settling = float(t[i] + f * (t[i + 1] - t[i]) - t_step)
    sse = float(s * (ref_after - np.mean(x[-n_tail:])))
    return StepMetrics(t_step, step * 1e3, overshoot, settling, rise, sse * 1e3, bool(settled))


def _smooth(t, x, cutoff_hz):
    fs = 1.0 / float(np.median(np.diff(t)))
    if not np.isfinite(cutoff_hz) or cutoff_hz >= 0.4 * fs or len(x) < 16:
        return x
    # scipy's butter(2, ...) and sosfiltfilt, ported bit for bit (analyses/numerics_iir.py): no scipy.signal import
    sos = butter_lowpass_sos(2, cutoff_hz, fs)
    return sosfiltfilt2(sos, x, padtype="constant" if len(x) < 30 else "odd",
                        padlen=min(len(x) - 1, 3 * int(fs / cutoff_hz)))


def step_response_metrics(t, x, x_ref, smooth: bool = True, min_step: float | None = None,
                          x_sensor: Sensor | None = None, ref_sensor: Sensor | None = None) -> pd.DataFrame:
    """Metrics of every step of a step run.

    Parameters
    ----------
    t : array_like
        Time. [s]
    x : array_like
        Position. [m]
    x_ref : array_like
        Reference. [m]
    smooth : bool
        Low-pass the position (zero phase) at ten times the inverse rise time before measuring.
    min_step : float, optional
        Smallest reference jump that counts as a step; default from the reference's sensor. [m]
    x_sensor, ref_sensor : Sensor, optional
        Resolution and noise of ``x`` and ``x_ref`` (run metadata); estimated when absent.

    Returns
    -------
    DataFrame
        One row per step: ``t_step_s``, ``step_mm``, ``overshoot_pct``, ``settling_time_s``,
        ``rise_time_s``, ``steady_state_error_mm``, ``position_resolution_mm`` (the quantisation
        step of ``x`` the metrics were measured with, metadata or estimated; 0 for a record
        that is not visibly quantised) [mm], ``settled``, ``note``, ``i_start``, ``i_end``.
        Metrics the position sensor cannot resolve are NaN with a ``note``. Empty when the
        reference never jumps.
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    cols = ["t_step_s", "step_mm", "overshoot_pct", "settling_time_s", "rise_time_s",
            "steady_state_error_mm", "position_resolution_mm", "settled", "note", "i_start", "i_end"]
    if x_sensor is None:
        x_sensor = describe_sensor(x)
    floor = x_sensor.floor()
    rows = []
    nan = float("nan")
    for i0, i1, before, after in find_steps(t, x_ref, min_step=min_step, sensor=ref_sensor):
        # the jump happened between samples i0-1 and i0: take the earlier one (the controller
        # at the logging rate reacts from the first sample of the new reference)
        t_step = float(t[i0])
        seg_t, seg_x = t[i0:i1], x[i0:i1]
        m = step_metrics(seg_t, seg_x, t_step, before, after)
        if smooth and np.isfinite(m.rise_time_s) and m.rise_time_s > 0 and len(seg_t) > 16:
            # filter over the whole run (no edge effect at the jump), then cut the step out
            xs = _smooth(t, x, 10.0 / m.rise_time_s)[i0:i1]
            m = step_metrics(seg_t, xs, t_step, before, after)
        size = abs(after - before)
        if not size >= N_SIGMA * floor:
            m = StepMetrics(t_step, m.step_mm, nan, nan, nan, nan, False,
                            f"step of {size:.3g} m is under {N_SIGMA:g} x the position sensor floor ({floor:.3g} m)")
        elif 0.02 * size < floor:
            m.overshoot_pct = m.settling_time_s = nan
            m.note = (f"the 2 % band ({0.02 * size:.3g} m) is finer than the position sensor floor "
                      f"({floor:.3g} m): no overshoot or settling time")
        elif not m.settled:
            m.note = "did not settle in the 2 % band within the record: no settling time"
        rows.append({**m.__dict__, "position_resolution_mm": x_sensor.resolution * 1e3, "i_start": i0, "i_end": i1})
    return pd.DataFrame(rows, columns=cols)


def plot_step_errors(steps: list[dict], title: str = ""):
    """Closed-loop steps like Fig. 15 of seed 000: position vs time, the error band as an inset.

    Main axes: the position relative to where the step started [mm] (``step_mm`` (1 - error/100))
    vs time since the step, one curve per step; up and down steps go their own ways, and
    curves that coincide (repeated runs) are told apart by line style and by markers at
    staggered times. Inset: the error in % of the step with the 2 % band, zoomed on the band.

    Parameters
    ----------
    steps : list of dict
        Each with ``t`` [s since the step], ``error_pct`` (``100 (x_ref - x) / step``), a
        ``label`` and ``step_mm`` [mm] (without it the position is drawn in % of the step).
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5.2))
    ax = fig.subplots()
    styles = ("-", "--", ":", "-.")
    markers = ("o", "s", "^", "v", "D", "x", "+", "*")
    signed = all("step_mm" in s for s in steps)
    t_end = 0.0
    for k, s in enumerate(steps):
        t = np.asarray(s["t"], float)
        err = np.asarray(s["error_pct"], float)
        pos = (s["step_mm"] if signed else 100.0) * (1 - err / 100.0)
        if t.size:
            t_end = max(t_end, float(t[-1]))
        every = max(1, t.size // 6)
        ax.plot(t, pos, ls=styles[k % len(styles)], lw=1.3, color=f"C{k % 10}", marker=markers[k % len(markers)],
                ms=5, markevery=(min(k * max(1, every // max(len(steps), 1)), max(t.size - 1, 0)), every),
                label=s.get("label", ""))
    ax.axhline(0, color="0.3", lw=0.6)
    ax.set_xlabel("time since the step [s]")
    ax.set_ylabel("position from the step start [mm]" if signed else "position [% of the step]")
    ax.grid(alpha=0.3)
    ax.set_title(title or "Closed-loop steps: position (the PLPA paper, Fig. 15); inset: error and the 2 % band")
    if steps:
        ins = ax.inset_axes([0.55, 0.30, 0.42, 0.36])
        for k, s in enumerate(steps):
            ins.plot(s["t"], s["error_pct"], ls=styles[k % len(styles)], lw=1.0, color=f"C{k % 10}")
        ins.axhspan(-2, 2, color="tab:green", alpha=0.15)
        ins.axhline(0, color="0.3", lw=0.5)
        ins.set_ylim(-6, 6)
        ins.set_xlim(0, t_end or 1.0)
        ins.set_ylabel("error [%]", fontsize=7)
        ins.tick_params(labelsize=7)
        ins.set_title("error in % of the step, 2 % band", fontsize=7)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=min(3, len(steps)),
                  frameon=False)
    fig.tight_layout()
    return fig

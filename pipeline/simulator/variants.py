"""How a lab exports a campaign's runs: the format variants per kind and the ``rig.toml`` per folder.

Formats are mixed as in a real lab (see :data:`VARIANTS`): every kind in at least two formats,
metadata embedded in some files and given by ``manifest.csv`` in others (with ``rig.toml``
defaults under both), a ``;`` + decimal-comma CSV with kPa and Nl/min, absolute pressures
(``bara``, ``bar(a)``), LVM with two segments and LVM with waveform timing (no X column), TDMS
with waveform timing and TDMS with two groups, MAT with a ``meta`` struct or numeric scalars,
a headerless whitespace text export described by ``rig.toml`` (encoder counts scaled there),
CSV columns renamed by ``rig.toml``, Excel workbooks (``meta`` sheet; a units row under the names,
described by ``rig.toml``) and ASAM MDF 4 files (metadata in the header comment) for every
characterisation kind, and non-canonical channels kept with their units (the
logger's ``temperature[degC]`` and ``rel_humidity[%]``, in CSV beside ``p_supply[bar]`` and in
TDMS with waveform timing, where ``t`` is the only canonical channel).
"""
from __future__ import annotations

#: Per kind, the ways its runs are exported (cycled over the runs of the kind). ``units``:
#: raw unit per channel; ``names``: raw channel names (mapped back by the folder's rig.toml);
#: ``embed``: metadata in the file (else in the folder's manifest.csv).
VARIANTS: dict[str, list[dict]] = {
    "leakage": [
        dict(fmt="csv", folder="leakage", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True),
        dict(fmt="csv", folder="leakage/eu", units={"p_supply": "kPa", "q_leak": "Nl/min"}, embed=False,
             opts=dict(delimiter=";", decimal=",")),
        dict(fmt="tdms", folder="leakage", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True,
             opts=dict(waveform=True)),
        dict(fmt="mat", folder="leakage", units={"p_supply": "Pa", "q_leak": "g/s"}, embed=True),
        dict(fmt="xlsx", folder="leakage/workbooks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True,
             opts=dict(units_row=True)),
    ],
    "breakaway": [
        dict(fmt="lvm", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True,
             opts=dict(segments=2, x_columns="One")),
        dict(fmt="csv", folder="breakaway", units={"p_a": "bara", "p_b": "bara", "x": "mm"}, embed=True),
        dict(fmt="tdms", folder="breakaway", units={"p_a": "kPa", "p_b": "kPa", "x": "um"}, embed=True,
             opts=dict(extra_group="Settings")),
        dict(fmt="lvm", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=False,
             opts=dict(x_columns="No")),
        dict(fmt="mf4", folder="breakaway", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True),
    ],
    "viscous": [
        dict(fmt="csv", folder="viscous", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True),
        dict(fmt="lvm", folder="viscous", units={"p_a": "bar", "p_b": "bar", "x": "mm"}, embed=True,
             opts=dict(x_columns="No")),
        dict(fmt="mf4", folder="viscous", units={"p_a": "kPa", "p_b": "kPa", "x": "mm"}, embed=True),
    ],
    "viscous_force": [
        dict(fmt="mat", folder="viscous", units={"f": "N", "x": "mm"}, embed=True, opts=dict(scalars=True)),
        dict(fmt="csv", folder="viscous", units={"f": "N", "x": "mm"}, embed=False),
    ],
    "identification": [
        dict(fmt="tdms", folder="identification", units={"x": "mm", "x_ref": "mm", "u": "V", "u_d": "mV"},
             embed=True, opts=dict(waveform=True)),
        dict(fmt="mat", folder="identification", units={"x": "m", "x_ref": "m", "u": "V", "u_d": "V"}, embed=True,
             opts=dict(scalars=True)),
        dict(fmt="mf4", folder="identification", units={"x": "mm", "x_ref": "mm", "u": "V", "u_d": "V"}, embed=True),
    ],
    "step": [
        dict(fmt="csv", folder="step", units={"x": "mm", "x_ref": "mm", "u": "V"}, embed=True),
        dict(fmt="lvm", folder="step", units={"x": "mm", "x_ref": "mm", "u": "mV"}, embed=True,
             opts=dict(x_columns="One")),
        dict(fmt="txt", folder="step/headerless", units={}, embed=False, headerless=True),
        dict(fmt="xlsx", folder="step", units={"x": "mm", "x_ref": "mm", "u": "V"}, embed=True),
    ],
    "spring": [
        dict(fmt="mat", folder="spring", units={"d": "mm", "f": "kN", "p": "bar(a)"}, embed=True),
        dict(fmt="csv", folder="spring/bench-pc", units={"d": "mm", "f": "N", "p": "bar(a)"}, embed=False,
             names={"d": "Displacement", "f": "Force", "p": "Pressure"}, opts=dict(delimiter="\t")),
        dict(fmt="xlsx", folder="spring", units={"d": "mm", "f": "N", "p": "bar(a)"}, embed=True),
    ],
    "pressure_step": [
        dict(fmt="lvm", folder="pressure_step", units={"p": "bar", "p_ref": "bar"}, embed=True,
             opts=dict(x_columns="One")),
        dict(fmt="csv", folder="pressure_step", units={"p": "bara", "p_ref": "bara"}, embed=True),
        dict(fmt="mf4", folder="pressure_step", units={"p": "bar", "p_ref": "bar"}, embed=True),
    ],
    "durability": [
        dict(fmt="tdms", folder="runs", units={"x": "mm", "p_a": "bar", "p_b": "bar"}, embed=True,
             opts=dict(waveform=True)),
        dict(fmt="csv", folder="runs", units={"x": "mm", "p_a": "bar", "p_b": "bar"}, embed=True),
    ],
    "timeseries": [
        dict(fmt="csv", folder="ambient", units={"p_supply": "bar", "temperature_degc": "degC",
                                                  "rel_humidity_pct": "%"},
             names={"temperature_degc": "temperature", "rel_humidity_pct": "rel_humidity"},
             embed=True, channels=["p_supply_pa", "temperature_degc", "rel_humidity_pct"]),
        dict(fmt="tdms", folder="ambient", units={"temperature_degc": "degC", "rel_humidity_pct": "%"}, embed=False,
             names={"temperature_degc": "Temperature", "rel_humidity_pct": "Rel. Humidity"},
             channels=["temperature_degc", "rel_humidity_pct"], opts=dict(waveform=True)),
    ],
    "leakage_check": [
        dict(fmt="csv", folder="leakage-checks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=True),
        dict(fmt="tdms", folder="leakage-checks", units={"p_supply": "bar", "q_leak": "l/min"}, embed=False,
             opts=dict(waveform=True)),
    ],
}

#: rig.toml written per folder: campaign defaults, the headerless export, the renamed channels.
RIG_TOMLS = {
    "plpa-2025/rig.toml": '# PLPA bench, characterisation campaign\n[metadata]\nrig = "plpa-1"\n'
                          'hose_area_m2 = 4.9e-4\noperator = "lab"\n',
    "plpa-2025/step/headerless/rig.toml": (
        '# Old controller PC: whitespace text, no header. Column 2 is the encoder count (5 um).\n'
        '[read]\ndelimiter = "whitespace"\ndecimal = "."\nskip_rows = 0\nheader = false\n\n'
        '[channels."1"]\nchannel = "t"\nunit = "s"\n\n'
        '[channels."2"]\nchannel = "x"\nunit = "mm"\nscale = 0.005\noffset = 0.0\n\n'
        '[channels."3"]\nchannel = "x_ref"\nunit = "mm"\n\n'
        '[metadata]\nkind = "step"\n'),
    "pla-2016/rig.toml": '# PLA cylinder on the hydraulic test machine\n[metadata]\nrig = "pla-1"\nstroke_mm = 40\n',
    "plpa-2025/leakage/workbooks/rig.toml": '# Spreadsheet exports: units in the row under the names\n[read]\nunits_row = 2\n',
    "pla-2016/spring/bench-pc/rig.toml": (
        '# The bench PC names channels in words\n[channels.Displacement]\nchannel = "d"\n\n'
        '[channels.Force]\nchannel = "f"\n\n[channels.Pressure]\nchannel = "p"\n'),
    # the endurance rig's encoder is stated (docs/inputs.md): at 5 Hz logging, 1 m strokes move
    # 200 mm between samples, too coarse for the record to show its 5 um quantisation
    "durability-2025/rig.toml": '[metadata]\nrig = "plpa-2"\nhose_area_m2 = 4.9e-4\n\n[sensors.x]\nresolution = "5 um"\n',
    "durability-2026/rig.toml": '[metadata]\nrig = "plpa-2"\nhose_area_m2 = 4.9e-4\n\n[sensors.x]\nresolution = "5 um"\n',
}

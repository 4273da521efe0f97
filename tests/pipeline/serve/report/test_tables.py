"""Rows as an HTML table: one number format per column, leaks under the flow sensor's floor,
the sensors text in display units."""
import pytest

from tests.pipeline.serve.report.conftest import table_cells


Q_SENSORS = ("p_supply: resolution 1, noise 307 (estimated) Pa; "
             "q_leak: resolution 1.98e-08, noise 3.93e-07 (estimated) kg/s")  # as leakage_map.sensors holds it


def test_a_leak_under_the_flow_sensors_floor_reads_below_it_and_a_column_keeps_one_format():
    from analyses.leakage import kg_s_to_l_min_anr
    from pipeline.serve.report.tables import html_table

    floor = float(kg_s_to_l_min_anr(3.93e-07))  # max(resolution, noise) of the flow sensor, in l/min ANR
    assert 0.019 < floor < 0.021
    cols = ["run_id", "pressure_bar", "leak_l_min", "leak_se_l_min", "sensors"]
    rows = [("r1", 5.0, -0.0019, 0.0027, Q_SENSORS), ("r2", 5.0, 4.313e-04, 0.002, Q_SENSORS),
            ("r3", 6.0, 0.7043, 0.003, Q_SENSORS), ("r4", 6.0, 14.7068, 0.01, Q_SENSORS)]
    cells = table_cells(html_table(cols, rows))
    # under the floor (the negative one too): "< floor"; the rest in the column's one format (3 decimals here)
    assert [r[2] for r in cells] == ["&lt; 0.020", "&lt; 0.020", "0.704", "14.707"]
    assert [r[1] for r in cells] == ["5", "5", "6", "6"]
    assert [r[3] for r in cells] == ["0.0027", "0.0020", "0.0030", "0.0100"]  # an uncertainty is never floored
    # without the sensors the floor is unknown: the values are shown, still in one format, no scientific notation
    cells = table_cells(html_table(cols[:4], [r[:4] for r in rows]))
    assert [r[2] for r in cells] == ["-0.002", "0.000", "0.704", "14.707"]
    # a sensors text that states no usable flow sensor gives no floor (the value is shown)
    from pipeline.serve.report.tables import flow_floor_l_min
    assert flow_floor_l_min(Q_SENSORS) == pytest.approx(floor)
    for bad in (None, "", "p_supply: resolution 1, noise 307 (estimated) Pa", "q_leak: resolution x, noise y (estimated) kg/s",
                "q_leak: resolution nan, noise nan (estimated) kg/s", "q_leak: resolution 0, noise 0 (estimated) kg/s"):
        assert flow_floor_l_min(bad) is None, bad
    cells = table_cells(html_table(cols, [("r1", 5.0, -0.0019, 0.0027, "q_leak: resolution x, noise y (estimated) kg/s")]))
    assert cells[0][2] == "-0.0019"
    # a column of tiny values alone is scientific throughout; one too wide for fixed notation as well
    cells = table_cells(html_table(["ae_m2"], [(1.541e-5,), (2.1e-6,)]))
    assert [r[0] for r in cells] == ["1.541e-05", "2.100e-06"]
    cells = table_cells(html_table(["n", "setting"], [(3, 3.5), (174544, 1300.0), (7, -0.0001)]))
    assert [r[0] for r in cells] == ["3", "174544", "7"] and [r[1] for r in cells] == ["3.5", "1300.0", "0.0"]


def test_the_sensors_column_is_shown_in_bar_and_l_min_but_stored_in_si():
    from pipeline.serve.report.tables import html_table

    stored = "p_supply: resolution 100, noise 40 (metadata) Pa; q_leak: resolution 1.975e-07, noise 0 (estimated) kg/s"
    cell = html_table(["run_id", "sensors"], [("r", stored)])
    assert "p_supply: resolution 0.001 bar, noise 0.0004 bar (metadata); q_leak: resolution 0.01 l/min" in cell
    assert " Pa" not in cell and "kg/s" not in cell

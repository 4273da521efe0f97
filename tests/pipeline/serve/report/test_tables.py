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


#: A coarser flow sensor (twice the noise: a floor near 0.04 l/min).
Q_COARSE = Q_SENSORS.replace("3.93e-07", "7.86e-07")


def leak_floor_db():
    """An in-memory warehouse with a hose check ``c/check-H1`` (its plateaus in ``leakage_map`` with
    their sensors, copied without them into ``hose_leak_growth``, one under the floor), a
    characterisation run of the same setting on a coarser sensor, and their ``seal_envelope``."""
    import duckdb

    con = duckdb.connect()
    con.execute("CREATE TABLE leakage_map (run_id VARCHAR, hose_id VARCHAR, chamber VARCHAR, adjustment VARCHAR, "
                "z_rollers_mm DOUBLE, spring_force_n DOUBLE, pressure_bar DOUBLE, leak_l_min DOUBLE, sensors VARCHAR)")
    con.execute("INSERT INTO leakage_map VALUES "
                "('c/check-H1', 'H1', 'A', 'distance', 4.0, NULL, 3.9969, -0.0044, ?), "
                "('c/check-H1', 'H1', 'A', 'distance', 4.0, NULL, 5.995, 0.6670, ?), "
                "('c/char', NULL, 'A', 'distance', 4.0, NULL, 6.0, 0.03, ?)", [Q_SENSORS, Q_SENSORS, Q_COARSE])
    con.execute("CREATE TABLE hose_leak_growth AS SELECT hose_id, run_id, 0.0 AS distance_km, chamber, pressure_bar, "
                "leak_l_min FROM leakage_map WHERE hose_id IS NOT NULL ORDER BY pressure_bar")
    con.execute("INSERT INTO hose_leak_growth VALUES ('H1', 'c/elsewhere', 1.0, 'A', 4.0, -0.0044)")  # no sensors
    con.execute("CREATE TABLE seal_envelope (chamber VARCHAR, adjustment VARCHAR, z_rollers_mm DOUBLE, "
                "spring_force_n DOUBLE, sealed_up_to_bar DOUBLE, first_leak_bar DOUBLE, max_leak_l_min DOUBLE, "
                "runs_used VARCHAR)")
    con.execute("INSERT INTO seal_envelope VALUES ('A', 'distance', 4.0, NULL, 6, NULL, 0.03, 'characterisation'), "
                "('A', 'distance', 4.0, NULL, 6, NULL, 0.03, 'hose_checks'), "
                "('B', 'distance', 4.0, NULL, 6, NULL, 0.001, 'characterisation')")
    return con


def test_rows_that_copy_leakage_plateaus_without_their_sensors_read_under_the_floor_of_the_run_they_came_from():
    """hose_leak_growth copies leakage_map's plateaus without the sensors: its leaks take the floor
    of their run (the same rule as leakage_map's rows: -0.0044 reads "< 0.0199" in both), a
    seal_envelope row the coarsest of the runs it used; the stored values are not changed."""
    from pipeline.serve.report.db import ReportDB
    from pipeline.serve.report.tables import coarsest_floor_l_min, flow_floor_l_min, html_table, leak_floors

    db = ReportDB(leak_floor_db())
    fine, coarse = flow_floor_l_min(Q_SENSORS), flow_floor_l_min(Q_COARSE)
    assert coarse == pytest.approx(2 * fine) and coarsest_floor_l_min([Q_SENSORS, None, Q_COARSE]) == coarse
    assert coarsest_floor_l_min([None, ""]) is None and coarsest_floor_l_min(None) is None
    cols, rows = db.rows("SELECT * FROM hose_leak_growth")
    floors = leak_floors(db, "hose_leak_growth", cols, rows)
    assert floors == [pytest.approx(fine), pytest.approx(fine), None]  # a run with no sensors stated: none
    cells = table_cells(html_table(cols, rows, floors=floors))
    assert [r[-1] for r in cells] == ["&lt; 0.0199", "0.6670", "-0.0044"]  # the floor at the column's decimals
    assert db.rows("SELECT leak_l_min FROM hose_leak_growth")[1][0] == (-0.0044,)  # stored as it was
    # the run's plateaus read as leakage_map's own rows (with their sensors) read them
    lcols, lrows = db.rows("SELECT run_id, pressure_bar, leak_l_min, sensors FROM leakage_map WHERE hose_id = 'H1'")
    assert [r[2] for r in table_cells(html_table(lcols, lrows))] == \
        [r[-1] for r in table_cells(html_table(cols, rows[:2], floors=floors[:2]))] == ["&lt; 0.020", "0.667"]
    # seal_envelope: the floor of the runs it used (characterisation: the coarse sensor; hose checks: the fine one)
    cols, rows = db.rows("SELECT * FROM seal_envelope")
    assert leak_floors(db, "seal_envelope", cols, rows) == [pytest.approx(coarse), pytest.approx(fine), None]
    cells = table_cells(html_table(cols, rows, floors=leak_floors(db, "seal_envelope", cols, rows)))
    assert [r[6] for r in cells] == ["&lt; 0.040", "0.030", "0.001"]
    # rows that state their own floor, tables without a leak column, a database without leakage_map: no list
    assert leak_floors(db, "leakage_map", lcols, lrows) is None
    assert leak_floors(db, "x", ["run_id", "pressure_bar"], [("c/check-H1", 4.0)]) is None
    import duckdb
    empty = ReportDB(duckdb.connect())
    assert leak_floors(empty, "hose_leak_growth", ["run_id", "leak_l_min"], [("c/check-H1", -0.0044)]) is None

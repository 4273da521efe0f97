-- Columns a person filters by, on every result table (pipeline/stages/__init__.py,
-- add_run_columns): a table with run_id gets the run's campaign (and hose_id when its runs name
-- hoses); an aggregated table states what it pools: the campaigns of the pooled runs (or of the
-- pooled hoses' logbooks) and how many runs. Added here, after every table of 10-30, so each
-- DDL file keeps its contract columns first.

-- leakage_map.campaign is in 10_plpa_characterisation.sql (its seal_envelope_at macro reads it)
ALTER TABLE breakaway ADD COLUMN campaign VARCHAR;
ALTER TABLE friction_dynamic ADD COLUMN campaign VARCHAR;
ALTER TABLE viscous_points ADD COLUMN campaign VARCHAR;
ALTER TABLE identification ADD COLUMN campaign VARCHAR;
ALTER TABLE step_response ADD COLUMN campaign VARCHAR;
ALTER TABLE spring_tests ADD COLUMN campaign VARCHAR;
ALTER TABLE spring_loop_energy ADD COLUMN campaign VARCHAR;
ALTER TABLE pressure_steps ADD COLUMN campaign VARCHAR;
ALTER TABLE durability_strokes ADD COLUMN campaign VARCHAR;
ALTER TABLE hose_leak_growth ADD COLUMN campaign VARCHAR;

ALTER TABLE seal_envelope ADD COLUMN campaigns VARCHAR[];        -- n_runs is already there
ALTER TABLE breakaway_summary ADD COLUMN campaigns VARCHAR[];
ALTER TABLE breakaway_summary ADD COLUMN n_runs BIGINT;
ALTER TABLE breakaway_findings ADD COLUMN campaigns VARCHAR[];
ALTER TABLE breakaway_findings ADD COLUMN n_runs BIGINT;
ALTER TABLE viscous_fits ADD COLUMN campaigns VARCHAR[];
ALTER TABLE viscous_fits ADD COLUMN n_runs BIGINT;
ALTER TABLE viscous_transition ADD COLUMN campaigns VARCHAR[];
ALTER TABLE viscous_transition ADD COLUMN n_runs BIGINT;
ALTER TABLE spring_fits ADD COLUMN campaigns VARCHAR[];
ALTER TABLE spring_fits ADD COLUMN n_runs BIGINT;
ALTER TABLE pressure_dynamics ADD COLUMN campaigns VARCHAR[];
ALTER TABLE pressure_dynamics ADD COLUMN n_runs BIGINT;
ALTER TABLE service_life ADD COLUMN campaigns VARCHAR[];         -- logbook campaigns of its hoses
ALTER TABLE hose_survival ADD COLUMN campaigns VARCHAR[];
ALTER TABLE service_life_test ADD COLUMN campaigns VARCHAR[];

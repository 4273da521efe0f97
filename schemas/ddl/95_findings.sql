-- Findings: each conclusion of the two seed papers as a check on the lab's latest data
-- (pipeline/stages/findings.py). One row per finding, in a fixed order (`ord`).

CREATE TABLE findings (
    finding_id      VARCHAR NOT NULL,     -- stable identifier, e.g. breakaway_0bar_twice
    ord             INTEGER,              -- display order
    paper           VARCHAR,              -- seed paper: PLPA (Carneiro 2020) / PLA (Palomares 2017)
    statement       VARCHAR NOT NULL,     -- the paper's conclusion, in words
    measured        DOUBLE,               -- the measured quantity (NULL: no data)
    uncertainty     DOUBLE,               -- its standard uncertainty (same unit), when defined
    unit            VARCHAR,              -- unit of measured / uncertainty
    criterion       VARCHAR,              -- when the finding holds, in words
    holds           BOOLEAN,              -- NULL when there is no data to check it
    n               BIGINT,               -- data points behind the value
    p_value         DOUBLE,               -- where a statistical test is behind it
    detail          VARCHAR,              -- how it was computed / "no data"
    source_tables   VARCHAR,              -- warehouse tables the value comes from
    previous_holds  BOOLEAN,              -- `holds` in the previous warehouse (rebuild fills it)
    change          VARCHAR,              -- the last change of `holds`: overturned / now holds / new data /
                                          -- no longer checkable, kept from rebuild to rebuild while `holds`
                                          -- stays the same (NULL: unchanged since first checked)
    changed_at      TIMESTAMPTZ           -- start of the rebuild that saw that change (NULL with change),
                                          -- the report alerts on changes of the last 24 hours
);

"""The morning report: ``warehouse/report/index.html``, one self-contained static page, and a
small page per run beside it (``report/runs/<safe id>.html``).

Built from the warehouse database alone (read-only), so ``pneubench report`` can rebuild it at
any time. It reads like a results section: a table of contents; the decision (per hose type the verdict
of force- against distance-set rollers in words, the information fraction, the plan, the verdict
under other failure definitions, the running hoses' remaining life and the looks); findings whose result changed
in the last 24 hours (``findings.changed_at``; an overturned one stays there through further
rebuilds that night); the findings; per paper each figure with the summary a reader compares it
to and the paper's tables beside the lab's values (paper value, measured value with its standard
uncertainty, difference), the rows behind them folded with a CSV download, each figure on a row
of its own (drawn near its full size); other figures, when a figure belongs to no paper; the
last rebuild (new, changed, deleted and quarantined inputs with their reasons); and every run.
Figures and downloads are embedded as data: URIs, the style is inline and there is no script:
the files open from disk anywhere. Every piece of text is escaped (``html.escape``): run
metadata, file names and quarantine reasons come from raw/.

The report is never silently stale. The rebuild renders it from the new database before the
swap, so a report that cannot be rendered fails the rebuild (exit 3): the previous warehouse
and its report stay, and they agree. ``pneubench report`` (``write_report``) replaces a page it
cannot render with a short page saying so, with the error, and raises ``ReportError``.
The index and its run pages are one folder, published whole with the database (``report`` is a
symlink to it, replaced by one rename).

The modules, from the bottom up:

- :mod:`~pipeline.serve.report.folders`: the report folder's file names (run pages, own files);
- :mod:`~pipeline.serve.report.markup`: style sheet, escaping, numbers and units as text;
- :mod:`~pipeline.serve.report.db`: the warehouse database as the report reads it;
- :mod:`~pipeline.serve.report.tables`: rows as an HTML table (units, formats, leak floors);
- :mod:`~pipeline.serve.report.sections`: the findings, the last rebuild, the contents;
- :mod:`~pipeline.serve.report.running_hoses`: the running hoses' remaining life and leak paths;
- :mod:`~pipeline.serve.report.decision`: the decision per hose type (words, bar, plan, the verdict
  under other failure definitions, the running hoses, looks);
- :mod:`~pipeline.serve.report.summaries`: per analysis, the summary and the papers' values;
- :mod:`~pipeline.serve.report.results`: per paper its figures, summaries and rows (``LAYOUT``);
- :mod:`~pipeline.serve.report.figures`: the report's own figures by key, taken from the previous report;
- :mod:`~pipeline.serve.report.channels`: the channels of one run as an SVG plot;
- :mod:`~pipeline.serve.report.pages`: the run pages and the index of runs;
- :mod:`~pipeline.serve.report.cache`: the data-only parts kept under the inputs and code key;
- :mod:`~pipeline.serve.report.publish`: staging a report folder and swapping it in whole;
- :mod:`~pipeline.serve.report.render`: the flow: render, stage, publish (``write_report``).
"""

"""The report's own figures by key: a key follows the inputs and the code that draws, a marked
figure is found again in a page, and a figure a previous page holds is taken, not drawn."""
from pipeline.serve.report import figures as rf


def test_a_figure_key_follows_its_inputs_and_its_code(tmp_path, monkeypatch):
    (tmp_path / "pkg").mkdir()
    src = tmp_path / "pkg" / "draw.py"
    src.write_text("A = 1\n")
    monkeypatch.setattr(rf, "ROOT", tmp_path)
    rf.code_key.cache_clear()
    code = rf.code_key(("pkg/*.py",), ("numpy",))
    assert code == rf.code_key(("pkg/*.py",), ("numpy",)) != rf.code_key(("pkg/*.py",))  # a library's version
    key = rf.figure_key(code, "samples/a-1.parquet", ["p_a_pa"], [("step", 0.5, None, "set-point step")])
    assert key == rf.figure_key(code, "samples/a-1.parquet", ["p_a_pa"], [("step", 0.5, None, "set-point step")])
    assert key != rf.figure_key(code, "samples/a-2.parquet", ["p_a_pa"], [("step", 0.5, None, "set-point step")])
    assert key != rf.figure_key(code, "samples/a-1.parquet", ["p_a_pa"], [("step", 0.5000001, None, "set-point step")])
    src.write_text("A = 2\n")  # the drawing code changed
    rf.code_key.cache_clear()
    assert rf.code_key(("pkg/*.py",), ("numpy",)) != code
    rf.code_key.cache_clear()


def test_a_figure_the_previous_page_holds_is_taken_and_the_others_are_drawn(tmp_path):
    k1, k2, k3 = (rf.figure_key("code", i) for i in range(3))
    page = tmp_path / "old.html"
    two = "<svg>\ntwo\n</svg>"
    page.write_text("<p>" + rf.marked(k1, "<svg>one</svg>") + "</p>\n<p>" + rf.marked(k2, two) + "</p>")
    figs = rf.Figures([page, tmp_path / "missing.html"])

    def never():
        raise AssertionError("drawn although held")

    assert figs.figure(k1, never) == rf.marked(k1, "<svg>one</svg>")
    assert figs.figure(k2, never) == rf.marked(k2, two)
    assert figs.figure(k3, lambda: "<svg>three</svg>") == rf.marked(k3, "<svg>three</svg>") and figs.drawn == 1
    assert figs.figure(rf.figure_key("code", 4), lambda: "") == ""  # nothing drawn: nothing marked
    assert rf.Figures().figure(k1, lambda: "<svg>new</svg>") == rf.marked(k1, "<svg>new</svg>")  # --full


def test_the_figures_of_a_page_are_found_as_the_marking_pattern_finds_them():
    """:func:`held_figures` (``str.find``) gives what the pattern of a marked figure matches, in
    order, for pages with broken, unclosed, nested and keyless markers too."""
    import random

    k1, k2 = rf.figure_key("code", 1), rf.figure_key("code", 2)
    page = ("<p>" + rf.marked(k1, "<svg>\none\n</svg>") + "<!-- figure: nothex -->" + rf.marked(k2, "")
            + "<!-- figure: " + k1 + " -->unclosed")
    assert rf.held_figures(page) == [(k1, "<svg>\none\n</svg>"), (k2, "")]
    rng = random.Random(26)
    bits = ["<!-- figure: ", "<!-- /figure -->", k1, k2[:31], " -->", "x", "\n", "<svg>", "0" * 32 + " -->"]
    for _ in range(5000):
        text = "".join(rng.choice(bits) for _ in range(rng.randint(0, 14)))
        assert rf.held_figures(text) == [(m.group(1), m.group(2)) for m in rf._MARKED.finditer(text)], text

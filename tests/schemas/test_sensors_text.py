"""schemas/sensors_text.py: the sensors cell read back as the stages write it, by its one reader."""
import math

from analyses.quality import Sensor
from schemas.sensors_text import sensor_part, sensor_parts


def test_each_channel_reads_back_as_describe_wrote_it_and_what_does_not_read_is_left_out():
    written = (f"p_supply: {Sensor(100.0, 40.0, 'metadata').describe()} Pa; "
               f"q_leak: {Sensor(2e-08, float('nan'), 'estimated').describe()} kg/s")
    parts = sensor_parts(written)
    assert parts["p_supply"] == (100.0, 40.0, "metadata", "Pa")
    res, noise, src, unit = parts["q_leak"]
    assert (res, src, unit) == (2e-08, "estimated", "kg/s") and math.isnan(noise)
    assert sensor_parts("hand-made note; x: resolution one, noise 2 (metadata) Pa") == {}
    assert sensor_parts(None) == {} and sensor_parts(float("nan")) == {}


def test_the_display_reads_the_text_with_this_one_reader(monkeypatch):
    import re

    import schemas.sensors_text as st
    from schemas.units import display_sensors_text

    text = "p_supply: resolution 100, noise 40 (metadata) Pa; x: resolution one, noise 2 (metadata) Pa"
    assert sensor_part(" p_supply: resolution 100, noise 40 (metadata) Pa ") == ("p_supply", 100.0, 40.0, "metadata", "Pa")
    assert sensor_part("x: resolution one, noise 2 (metadata) Pa") is None
    assert display_sensors_text(text) == ("p_supply: resolution 0.001 bar, noise 0.0004 bar (metadata); "
                                          "x: resolution one, noise 2 (metadata) Pa")
    # a different reading of the text changes both the stages' reading and the display's: one reader
    monkeypatch.setattr(st, "SENSOR_PART", re.compile(r"(?!)"))
    assert sensor_parts(text) == {} and display_sensors_text(text) == text

"""pipeline/stages/sensors_text.py: the sensors cell read back as the stages write it."""
import math

from analyses.quality import Sensor
from pipeline.stages.sensors_text import sensor_parts


def test_each_channel_reads_back_as_describe_wrote_it_and_what_does_not_read_is_left_out():
    written = (f"p_supply: {Sensor(100.0, 40.0, 'metadata').describe()} Pa; "
               f"q_leak: {Sensor(2e-08, float('nan'), 'estimated').describe()} kg/s")
    parts = sensor_parts(written)
    assert parts["p_supply"] == (100.0, 40.0, "metadata", "Pa")
    res, noise, src, unit = parts["q_leak"]
    assert (res, src, unit) == (2e-08, "estimated", "kg/s") and math.isnan(noise)
    assert sensor_parts("hand-made note; x: resolution one, noise 2 (metadata) Pa") == {}
    assert sensor_parts(None) == {} and sensor_parts(float("nan")) == {}

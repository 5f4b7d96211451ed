"""Embodiment files: MVPd presets load; bad values give one-line errors naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.config import ConfigError, load_embodiment

PRESETS = Path(__file__).resolve().parents[2] / "jobs" / "embodiments"


def test_mvpd_presets_load_with_mvpd_camera_and_lights():
    mvpd = load_embodiment(PRESETS / "mvpd.yaml")
    fx, fy, cx, cy = mvpd.sensor.intrinsics()
    assert (mvpd.sensor.width, mvpd.sensor.height, mvpd.placements) == (640, 480, [1.0, 0.1])
    assert fx == pytest.approx(465.6029, abs=1e-4) and fy == fx and (cx, cy) == (320.0, 240.0)
    assert (mvpd.sensor.near, mvpd.sensor.far, mvpd.illumination.kind) == (0.01, 1000.0, "ambient")
    for watts in (20, 200):
        spot = load_embodiment(PRESETS / f"mvpd_spot{watts}.yaml")
        assert spot.illumination.kind == "spot" and spot.illumination.power == watts
        assert (spot.illumination.cone, spot.illumination.blend) == (180.0, 1.0)
        # The authors' Cycles material (render_config.ini) and light paths (16 bounces).
        light = spot.illumination
        assert (light.material, light.specular, light.roughness, light.indirect.bounces) == ("principled", 1.0, 0.5, 16)
        assert spot.sensor == mvpd.sensor and spot.body == mvpd.body and spot.placements == mvpd.placements


@pytest.mark.parametrize(("change", "field"), [
    ("  hfov: 69.0", "sensor.hfov"),
    ("  radius: 0.1", "body.radius"),
    ("placements: [1.0, 0.1]", "placements"),
])
def test_bad_values_name_the_file_and_the_field(tmp_path, change, field):
    bad = {"  hfov: 69.0": "  hfov: 0.0", "  radius: 0.1": "  radius: -0.1",
           "placements: [1.0, 0.1]": "placements: [2.0, 0.1]"}[change]  # zero fov, negative radius, camera above body
    text = (PRESETS / "mvpd.yaml").read_text().replace(change, bad, 1)
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as error:
        load_embodiment(path)
    message = str(error.value)
    assert str(path) in message and field in message and "\n" not in message

"""What the Gallery says a command prints, the command prints (issue 36 item 5): the
actively damped beam's `phc check` "certifies the plant and says that the controller may
inject energy" — the feedback source's line of the certificate says so."""

from __future__ import annotations

import re
from pathlib import Path

import phc

REPO = Path(__file__).resolve().parents[1]


def test_phc_check_of_the_controlled_beam_says_what_the_gallery_claims():
    gallery = " ".join((REPO / "docs" / "gallery.md").read_text(encoding="utf-8").split())
    assert "`phc check` certifies the plant and says that the controller may inject energy" in gallery
    report = phc.certify_model(REPO / "models" / "controlled_beam.yaml", samples=0)
    text = report.render_text()
    assert report.certified
    (actuator,) = [line for line in text.splitlines() if re.match(r"\s+actuator\s", line)]
    assert "Dirac ok" in actuator and "the controller may inject energy" in actuator
    assert "tip.p" in actuator  # the state it reads
    (hammer,) = [line for line in text.splitlines() if re.match(r"\s+hammer\s", line)]
    assert "inject" not in hammer  # a source of t alone is an input, not a controller


def test_phc_check_of_the_pi_controlled_motor_says_what_the_gallery_claims():
    gallery = (REPO / "docs" / "gallery.md").read_text(encoding="utf-8")
    report = phc.certify_model(REPO / "models" / "dc_motor_pi.yaml", samples=0)
    text = report.render_text()
    assert report.certified
    for name in ("supply", "speed_control"):
        (line,) = [line for line in text.splitlines() if re.match(rf"\s+{name}\s", line)]
        assert line in gallery, line
    assert "signal block: outside the port-Hamiltonian certificate" in text

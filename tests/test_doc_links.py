"""The README's and the docs' relative links lead somewhere: the file exists, and an anchor names one of its headings."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "reports").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]*)\)")


def heading_to_anchor(heading: str) -> str:
    """A Markdown heading's text -> the anchor GitHub gives it: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    return {heading_to_anchor(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", page.read_text(), re.M)}


def test_heading_to_anchor_follows_githubs_rule():
    assert heading_to_anchor("Ablation: each switch, L = 3 sensors") == "ablation-each-switch-l--3-sensors"
    assert heading_to_anchor("Sensor poses from forward kinematics (`sensors.pose_sigma_mm`, `sensors.pose_sigma_deg`)") \
        == "sensor-poses-from-forward-kinematics-sensorspose_sigma_mm-sensorspose_sigma_deg"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_lead_somewhere(page):
    broken = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            broken.append(f"{target}: no such file")
        elif anchor and linked.suffix == ".md" and anchor not in anchors(linked):
            broken.append(f"{target}: no such heading")
    assert not broken, broken

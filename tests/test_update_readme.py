import importlib.util
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location("update_readme", Path(__file__).parents[1] / "scripts" / "update_readme.py")
update_readme = importlib.util.module_from_spec(spec)
spec.loader.exec_module(update_readme)

PAGE = """Generated on a day.

### The paper's 40 triplets (test set), L = 3

| a | b |

### Per object (caddeo2023)

| c |

### Off-axis scenes (generated; sensors tilted and touching off the gel's centre)

![x](figures/x.png)

### Which object: identification over the library

| e |

### Ablation: each switch, L = 1, 2, 3 sensors

| d |
"""


def test_the_readme_gets_the_headline_sections_and_a_link_to_the_rest():
    body = update_readme.headline(PAGE)
    assert body.startswith("Generated on a day.")
    assert "| a | b |" in body and "](reports/figures/x.png)" in body and "| e |" in body
    assert "| c |" not in body and "| d |" not in body
    assert "on [reports/results.md](reports/results.md): Per object, Ablation." in body
    assert body.index("The paper's 40") < body.index("Off-axis")


def test_a_page_without_a_headline_section_is_an_error():
    with pytest.raises(ValueError, match="lacks the sections"):
        update_readme.headline(PAGE.replace("### Per object (caddeo2023)", "").replace("### Off-axis", "### Other"))

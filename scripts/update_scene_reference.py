"""Regenerate the scene reference in docs/scenes.md from the code's schema.

python scripts/update_scene_reference.py
"""

import pathlib
import re

from skfem_modal.scene import schema_markdown

DOC = pathlib.Path(__file__).resolve().parents[1] / "docs" / "scenes.md"
BEGIN = "<!-- BEGIN GENERATED: skfem-modal info --scene-reference -->"
END = "<!-- END GENERATED -->"

text = DOC.read_text()
new = re.sub(
    re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: f"{BEGIN}\n{schema_markdown()}\n{END}", text, flags=re.S
)
DOC.write_text(new)
print(f"updated {DOC}")

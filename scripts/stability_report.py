"""The hard cases of tests/hard_cases.py as a markdown table, for docs/stability.md.

python scripts/stability_report.py
"""

import os
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
import hard_cases as H  # noqa: E402


def fmt(value):
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "NO"
    if isinstance(value, (int, np.integer)):
        return str(value)
    return f"{value:.1e}"


def main():
    print(f"Measured {time.strftime('%Y-%m-%d')} on {os.cpu_count()} cores.\n")
    print(
        "| case | finite | energy gained in a step (no input) | COM drift (floating) | worst contact penetration "
        "| after contact resolves | identical rerun | notes |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in H.CASES:
        out = H.case(name)
        notes = []
        if "max_aspect_ratio" in out:
            notes.append(f"largest aspect ratio {out['max_aspect_ratio']:.0f}")
        if "inverted_at_start" in out:
            notes.append(
                f"{out['inverted_at_start']} inverted elements at the start, {out['inverted_at_end']} at the end"
            )
        print(
            f"| {name} | {fmt(out['finite'])} | {fmt(out.get('energy_growth'))} | {fmt(out.get('com_drift'))} "
            f"| {fmt(out.get('worst_penetration'))} | {fmt(out.get('penetration_after_contact'))} "
            f"| {fmt(out['identical_rerun'])} | {'; '.join(notes)} |"
        )
        sys.stdout.flush()
    for contact_model, scales in (("reference", (1e-3, 1e3)), ("coulomb", (2.0**-10, 2.0**10))):
        base, iterations = H.scaled_motion(1.0, contact_model)
        for scale in scales:
            scaled, scaled_iterations = H.scaled_motion(scale, contact_model)
            diff = np.abs(scaled - base).max() / np.abs(base).max()
            same = "the same" if scaled_iterations == iterations else "other"
            print(
                f"\nCoordinates x {scale:g} (stiffness x {scale**2:g}, gravity x {scale:g}), {contact_model} contact: "
                f"largest difference of the motion (divided by the scale) {diff:.1e} of the body size, {same} "
                "iterations step for step."
            )


if __name__ == "__main__":
    main()

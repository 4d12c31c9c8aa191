"""Committed figures at about a third of their bytes: PNGs rewritten as 256-colour palette PNGs.

    python benchmarks/compact_pngs.py PATH [PATH ...]
    python benchmarks/compact_pngs.py notebooks/quickstart.ipynb

Every device call of the GPU campaign carries the working tree, and what the tree weighs is
taken from the room the device packs leave (``benchmarks/device_pack.py``: 8.27 MB on
2026-12-04), so the results we commit must stay small. Our figures are line plots and
heatmaps in a few dozen colours with antialiased edges: a palette of 256 colours, chosen per
image (median cut), holds them with no difference one sees, at 30-40% of matplotlib's RGBA
bytes (``min_score.png`` of the 340k-step Hopper run: 229 kB, 86 kB as a palette PNG). Each
PATH is a PNG, a Jupyter notebook (its PNG outputs, kept in the notebook as base64) or a
folder searched for both; a figure is rewritten only where that makes it smaller, and one
already in palette mode is left as it is. The plots themselves still write full-colour PNGs
(and PDFs), for anyone who reads colours as numbers; a notebook run again writes them too.
"""

from __future__ import annotations

import base64
import io
import json
import os
import sys

from PIL import Image

PALETTE_COLOURS = 256


def palette_png(image: Image.Image) -> bytes:
    """``image`` as a palette PNG of at most 256 colours (median cut), optimised."""
    out = io.BytesIO()
    image.convert("RGB").quantize(PALETTE_COLOURS, method=Image.Quantize.MEDIANCUT).save(out, format="PNG", optimize=True)
    return out.getvalue()


def smaller_png(png: bytes) -> bytes:
    """``png`` as :func:`palette_png` where that is smaller, else ``png`` itself (also where it
    is in palette mode already)."""
    with Image.open(io.BytesIO(png)) as image:
        if image.mode == "P":
            return png
        smaller = palette_png(image)
    return smaller if len(smaller) < len(png) else png


def compact(path: str) -> tuple[int, int]:
    """Rewrite one PNG, or each PNG output of a notebook (``.ipynb``), as :func:`smaller_png`;
    (file bytes before, after)."""
    with open(path, "rb") as file:
        before = file.read()
    if path.lower().endswith(".ipynb"):
        notebook = json.loads(before)
        for cell in notebook["cells"]:
            for output in cell.get("outputs", []):
                data = output.get("data", {})
                if "image/png" in data:
                    png = smaller_png(base64.b64decode(data["image/png"]))
                    data["image/png"] = base64.b64encode(png).decode("ascii")
        after = (json.dumps(notebook, sort_keys=True, indent=1, ensure_ascii=False) + "\n").encode()  # nbformat's layout
    else:
        after = smaller_png(before)
    if len(after) >= len(before):
        return len(before), len(before)
    with open(path, "wb") as file:
        file.write(after)
    return len(before), len(after)


def png_files(paths: list[str]) -> list[str]:
    """The PNGs and notebooks these paths name, folders searched; ValueError for a path that is neither."""
    found, kinds = [], (".png", ".ipynb")
    for path in paths:
        if os.path.isdir(path):
            found += sorted(os.path.join(folder, name) for folder, _, names in os.walk(path)
                            for name in names if name.lower().endswith(kinds))
        elif os.path.isfile(path) and path.lower().endswith(kinds):
            found.append(path)
        else:
            raise ValueError(f"{path}: not a PNG file, a notebook nor a folder")
    return found


def main(argv: list[str]) -> None:
    from admissable_jax.cli import fail

    if any(arg in ("-h", "--help") for arg in argv):
        print(__doc__.strip())
        return
    try:
        if not argv:
            raise ValueError("give the PNG files, notebooks or folders to compact: python benchmarks/compact_pngs.py PATH [PATH ...]")
        files = png_files(argv)
    except ValueError as error:
        fail(str(error))
    total_before = total_after = 0
    for path in files:
        before, after = compact(path)
        total_before, total_after = total_before + before, total_after + after
        print(f"{path}: {before:,} -> {after:,} bytes")
    print(f"{len(files)} file(s): {total_before:,} -> {total_after:,} bytes")


if __name__ == "__main__":
    main(sys.argv[1:])

"""``photonflow demo``: the main job on the embedded default detectors."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..cli_errors import check_output_folder
from .root import console


def demo(
    out_dir: Annotated[Path, typer.Option(
        "--out-dir", help="Folder for the demo's pictures and files.",
    )] = Path("demo_output"),
    skip_fit: Annotated[bool, typer.Option(
        "--skip-fit", help="Leave out the optics calibration fit and the reconstruction"
                           " (minutes on a laptop CPU).",
    )] = False,
) -> None:
    """Run the main job on the embedded default detectors and write its outputs."""
    from ..demo import demo_steps, run_demo

    check_output_folder(out_dir, "--out-dir")
    run_demo(out_dir, console(), demo_steps(with_fit=not skip_fit))

"""Sphinx configuration for the diffusion-pr documentation."""
from __future__ import annotations

import contextlib
import importlib
import io
import os
import sys

from docutils import nodes
from docutils.parsers.rst import Directive

sys.path.insert(0, os.path.abspath(".."))

project = "diffusion-pr"
author = "diffusion-pr developers"
release = "0.1.0"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
]
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build"]
napoleon_numpy_docstring = True
napoleon_google_docstring = False
napoleon_use_ivar = True
autodoc_typehints = "description"
autodoc_member_order = "bysource"
autodoc_default_options = {"members": True, "undoc-members": False}
suppress_warnings = ["myst.header"]
nitpicky = False
html_theme = "alabaster"

CLI_MODULES = {"diffusion-pr": "diffusion_pr.cli", "gfmd-ref": "gfmd_ref.cli"}


class CliHelp(Directive):
    """``{cli-help} PROGRAM [SUBCOMMAND]``: the command's own ``--help`` text, generated from its argparse parser."""

    required_arguments = 1
    optional_arguments = 1

    def run(self) -> list:
        program, *sub = self.arguments
        out = io.StringIO()
        os.environ["COLUMNS"] = "100"
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
            importlib.import_module(CLI_MODULES[program]).main([*sub, "--help"])
        return [nodes.literal_block(text=out.getvalue().rstrip())]


def setup(app) -> None:
    app.add_directive("cli-help", CliHelp)

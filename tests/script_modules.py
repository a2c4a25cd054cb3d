"""The repository's scripts (benchmarks, research scripts) imported as modules for their tests, without running
their ``main``."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_script(relative: str):
    """The script at ``relative`` (to the repository root) as a module, registered in ``sys.modules`` under a name
    of its own (a dataclass looks its module up there)."""
    path = ROOT / relative
    name = "_script_" + path.with_suffix("").as_posix().replace("/", "_").replace("-", "_")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module

"""Loading and validation of a crane file, by default the packaged ``config/crane.yaml``.

:func:`load_config` reads a YAML file and :func:`parse_config` turns the parsed mapping into the
:class:`~crane_reference.model.description.CraneDescription` it describes.  Two layouts are read:

* the description layout (:mod:`.description_layout`, a top-level ``links`` list): any serial crane;
* a URDF and its overlay (:mod:`.urdf_layout`, a top-level ``urdf`` path): the chain from the URDF, the
  flexible links, springs, drive and task from the overlay;
* the paper's crane family (:mod:`.paper_layout`, top-level ``boom`` and ``link4``): the layout of the paper's
  crane with its numbers, read as the chain it describes.

Every problem raises :class:`ConfigError` whose message names the source, the dotted path of the
field, the offending value and what is allowed, e.g.::

    crane.yaml: base.mass = -3.0: must be a finite number > 0 [kg]
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from .description import CraneDescription
from .description_layout import parse_description
from .fields import FieldError
from .paper_layout import paper_description, parse_parameters
from .urdf_layout import parse_urdf_description

PACKAGE = "crane_reference"
DEFAULT_FILE = Path("config") / "crane.yaml"
LAYOUTS = {"links": "the description layout", "urdf": "a URDF and its overlay", "boom": "the paper's crane layout"}
"""The top-level key that marks each layout."""


class ConfigError(ValueError):
    """An invalid or unreadable crane configuration."""


def default_config_path() -> Path:
    """The packaged ``config/crane.yaml``: next to the package source (a source checkout or an
    editable install), else in the package's ament share directory (an installed ROS package)."""
    return packaged_file(DEFAULT_FILE)


def packaged_file(relative: Path) -> Path:
    """A file of the package's share directory (``config/...``): next to the package source, else in the
    package's ament share directory."""
    source_tree = Path(__file__).resolve().parents[2] / relative
    if source_tree.is_file():
        return source_tree
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(PACKAGE)) / relative
    except (ImportError, LookupError, OSError) as err:
        raise ConfigError(f"no {relative}: {source_tree} does not exist and the ament "
                          f"index has no share directory for {PACKAGE} ({err})") from err
    if not installed.is_file():
        raise ConfigError(f"no {relative}: neither {source_tree} nor {installed} exists")
    return installed


class _Yaml12FloatLoader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``1e6`` and ``2.1e11`` as numbers (YAML 1.1,
    which PyYAML implements, requires a dot and a signed exponent)."""


_Yaml12FloatLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+$"),
    list("-+0123456789."),
)


def read_yaml(path: str | os.PathLike[str]) -> Any:
    """The parsed YAML of a file (YAML 1.2 floats); :class:`ConfigError` naming the file if it cannot be read."""
    file = Path(path)
    try:
        with file.open(encoding="utf-8") as stream:
            return yaml.load(stream, Loader=_Yaml12FloatLoader)
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{file}: cannot read: {err}") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{file}: not valid YAML: {err}") from err


def load_config(path: str | os.PathLike[str] | None = None) -> CraneDescription:
    """Read and validate a crane file; ``None`` loads :func:`default_config_path`; a relative path that does not
    exist from the working directory is looked up in the package's ``config/`` (so ``loader_crane.yaml`` names
    the packaged example).

    Raises :class:`ConfigError` (naming the file) if the file cannot be read, is not valid YAML or
    does not describe a valid crane.
    """
    file = default_config_path() if path is None else Path(path)
    if not file.is_absolute() and not file.exists():
        with contextlib.suppress(ConfigError):  # else reading the path as given names it in the error
            file = packaged_file(DEFAULT_FILE.parent / file)
    return parse_config(read_yaml(file), source=str(file))


def parse_config(data: Mapping[str, Any], source: str = "<dict>") -> CraneDescription:
    """Validate a crane file's mapping (what ``yaml.safe_load`` gives) in either layout (module docstring).

    ``source`` names the origin of ``data`` in error messages.  Vectors become float arrays of shape
    (3,), inertia tensors float arrays of shape (3, 3).
    """
    try:
        if isinstance(data, Mapping) and "links" in data:
            return parse_description(data)
        if isinstance(data, Mapping) and "urdf" in data:
            return parse_urdf_description(data, Path(source) if Path(source).is_file() else None)
        if isinstance(data, Mapping) and "boom" in data:
            return paper_description(parse_parameters(data))
        keys = ", ".join(f"'{key}' ({layout})" for key, layout in LAYOUTS.items())
        raise FieldError(f"<top level>: must be a mapping with one of the keys {keys}")
    except FieldError as err:
        raise ConfigError(f"{source}: {err}") from None

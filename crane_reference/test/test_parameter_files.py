"""The files generated from the nodes' parameter tables (:mod:`crane_reference.ros.parameter_generation`): each is
up to date, and each agrees with its table when read back as a user's tools read it (PyYAML, the Python types,
the Markdown table's cells)."""

from __future__ import annotations

import dataclasses
import re

import pytest
import yaml

from crane_reference.ros.parameter_generation import COMMAND, TABLES, generated_files
from crane_reference.ros.parameter_spec import ParameterSpec
from crane_reference.ros.parameter_values import (
    ControllerParameterValues,
    NodeParameterValues,
    PlantParameterValues,
)

VALUES = {"NodeParameterValues": NodeParameterValues, "PlantParameterValues": PlantParameterValues,
          "ControllerParameterValues": ControllerParameterValues}


@pytest.mark.parametrize("path", list(generated_files()), ids=lambda path: path.name)
def test_generated_file_is_up_to_date(path) -> None:
    assert path.read_text() == generated_files()[path], f"{path} is stale: run `{COMMAND}` and commit it"


@pytest.mark.parametrize("table", TABLES, ids=lambda table: table.node)
def test_parameters_file_holds_each_default(table) -> None:
    """Read by PyYAML as rclpy's params-file parser reads it: every parameter whose default is the table's, at
    that default with the parameter's type; those from the crane file or the crane commented out."""
    path = next(path for path in generated_files() if path.name == table.config)
    values = yaml.safe_load(path.read_text())["/**"]["ros__parameters"]
    fixed = [spec for spec in table.table if spec.from_config is None and not spec.per_joint]
    assert list(values) == [spec.name for spec in fixed]
    for spec in fixed:
        value = values[spec.name]
        assert spec.check(spec.coerce(value)) is None and value == spec.default, spec.name
        assert type(spec.coerce(value)) is type(spec.default), spec.name  # 3.0, not "3.0" or 3


@pytest.mark.parametrize("table", TABLES, ids=lambda table: table.node)
def test_typed_values_have_a_field_per_row(table) -> None:
    """The generated class has one field per row, in its order, typed as the row: a per-joint row as a dict."""
    python_types = {"BOOL": "bool", "INTEGER": "int", "DOUBLE": "float", "STRING": "str",
                    "STRING_ARRAY": "tuple[str, ...]"}
    fields = dataclasses.fields(VALUES[table.values_class])
    assert [f.name for f in fields] == [spec.name.replace(".<joint>", "").replace(".", "_") for spec in table.table]
    for f, spec in zip(fields, table.table, strict=True):
        scalar = python_types[spec.ros_type.name]
        assert f.type == (f"dict[str, {scalar}]" if "<joint>" in spec.name else scalar), spec.name


def _doc_rows(text: str, node: str) -> list[list[str]]:
    section = text.split(f"## {node} ")[1].split("\n## ")[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    return [[cell.strip() for cell in re.split(r"(?<!\\)\|", row)[1:-1]] for row in rows]


@pytest.mark.parametrize("table", TABLES, ids=lambda table: table.node)
def test_docs_row_per_parameter(table) -> None:
    """docs/parameters.md has a row per parameter, in the table's order, with its type, unit, range or choices,
    read-only flag and default."""
    path = next(path for path in generated_files() if path.name == "parameters.md")
    rows = _doc_rows(path.read_text(), table.node)
    assert [row[0] for row in rows] == [f"`{spec.name}`" for spec in table.table]
    for row, spec in zip(rows, table.table, strict=True):
        spec: ParameterSpec
        assert row[1].replace(" ", "_").upper() == spec.ros_type.name, spec.name
        assert row[3] == spec.unit.replace("|", "\\|") and row[5] == ("yes" if spec.read_only else "no"), spec.name
        if spec.bounds is not None:
            low, high = (float(x) for x in row[4].strip("[]").split(","))
            assert (low, high) == tuple(map(float, spec.bounds)), spec.name
        if spec.choices:
            assert re.findall(r"`([^`]*)`", row[4]) == list(spec.choices), spec.name
        if not spec.per_joint:
            assert yaml.safe_load(re.search(r"`([^`]*)`", row[2]).group(1)) == spec.default, spec.name

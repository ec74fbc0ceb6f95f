"""The parameter file: schema (names, units, meaning), loading, overrides and validation.

The schema is the single source of truth for parameter names and units; the C header,
the manifest, the report tables and ``maglevgen params show`` all read it. Values live in the
TOML file (the default one describes the LLNL carriage of the paper, with the reason for each
value the paper does not give written beside it).

The package, bottom up: ``fields`` (a section's model, its range check, the schema's error),
``sections`` (one model per table of the file), ``vector`` (the schema flattened into the
parameter vector), ``document`` (`Parameters`: the whole file, its provenance and the rules
across sections), ``reference`` (the schema as rows for people), ``options`` (command-line
numbers checked against the schema's ranges) and ``loading`` (reading a file, ``--set``,
the one-line errors). Every name a caller uses is imported from here.
"""

from __future__ import annotations

# the derivation's choices, which maglevgen.analyses.envelope imports from here
from maglevgen.derive.structure import CIRCUIT_DYNAMICS as CIRCUIT_DYNAMICS
from maglevgen.params.document import Parameters, entry_limits, schema_unit, with_sensor_values
from maglevgen.params.loading import (
    LoadedParams,
    default_params_path,
    default_params_text,
    load_params,
    parse_override,
    validate,
)
from maglevgen.params.options import check_count, check_key_option, check_option, check_run_options
from maglevgen.params.reference import annotate_with_units, schema_rows, schema_table
from maglevgen.params.sections import (
    ACTUATOR_LAG,
    ACTUATOR_MODELS,
    ARRAY_FORCE_LAWS,
    LOOP_TOLERANCES,
    NORMAL_TRUNCATION,
    PAPER_ARRAY_FORCE,
    SENSOR_TOLERANCES,
    ModelChoices,
)
from maglevgen.params.vector import flatten, schema_leaves

__all__ = ["ACTUATOR_LAG", "ACTUATOR_MODELS", "ARRAY_FORCE_LAWS", "CIRCUIT_DYNAMICS",
           "LOOP_TOLERANCES", "NORMAL_TRUNCATION", "PAPER_ARRAY_FORCE", "SENSOR_TOLERANCES",
           "LoadedParams", "ModelChoices", "Parameters", "annotate_with_units", "check_count",
           "check_key_option", "check_option", "check_run_options", "default_params_path",
           "default_params_text", "entry_limits", "flatten", "load_params", "parse_override",
           "schema_leaves", "schema_rows", "schema_table", "schema_unit", "validate",
           "with_sensor_values"]

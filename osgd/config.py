"""Pipeline configs: TOML files in ``pipelines/``, validated per stage.

A config has a ``[pipeline]`` section (``name``, ``seed``) and one section
per stage, named after the stage (``[models]``, ``[grasps]``, ``[checks]``,
``[scenes]``, ``[samples]``); a missing section means all defaults. An
optional ``[executor]`` section says where the items run
(:class:`ExecutorSection`), which changes no shard. Any value
can be overridden with ``section.key=value`` (the value is read as TOML, so
``3``, ``0.5``, ``true``, ``"text"`` and ``[1, 2]`` all work; a bare word is
a string), and a key of a parameter group with ``section.group.key=value``
(``scenes.split.by=model`` sets ``by`` of ``[scenes.split]``).

Values are checked strictly: a string or a boolean is no integer (``count =
"4"`` and ``count = true`` are errors), an integer is a valid float. Each
problem is one line naming the file (or the override that set the value),
``[section] key = value`` and what is allowed; an unknown key lists the
section's keys.

Strings may name environment variables as ``${NAME}`` or ``${NAME:-default}``.
Relative paths in location fields are resolved against the config file's
folder.
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from osgd.contract.taxonomy import TABLE1, Taxonomy, TaxonomyError, read_taxonomy
from osgd.errors import InputError
from osgd.stage import StageParams

_Model = TypeVar("_Model", bound=BaseModel)


class ConfigError(ValueError):
    """A pipeline config that cannot be used; the message names file, key and value."""


class PipelineSection(BaseModel):
    """The ``[pipeline]`` section.

    Attributes
    ----------
    name : str
        Names the manifest (``<data-dir>/manifests/<name>.json``).
    seed : int
        Every random draw of every stage derives from it.
    taxonomy : str
        A taxonomy file that extends Table I (``docs/taxonomy.md``), relative to the config's folder (held
        resolved); empty for the packaged Table I. Its content, not its path, enters the keys of the shards
        it labels.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    seed: int = 0
    taxonomy: str = ""


class ExecutorSection(BaseModel):
    """The ``[executor]`` section: where the work items run, not what they build.

    It enters no shard key and no manifest: the same pipeline built by any
    executor gives the same shards. ``osgd --executor`` and
    ``--ray-address`` override it.

    Attributes
    ----------
    backend : str
        ``"process"`` (local worker processes) or ``"ray"``.
    ray_address : str
        The Ray cluster to join; empty for ``RAY_ADDRESS`` or a local instance.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    backend: Literal["process", "ray"] = Field(
        "process", description='where items run: "process" (worker processes on this machine) or "ray" (a Ray cluster)'
    )
    ray_address: str = Field(
        "",
        description='the Ray cluster to join ("auto", "HOST:6379", "ray://HOST:10001"); '
        "empty: RAY_ADDRESS, else a Ray instance on this machine",
    )


@dataclass(frozen=True)
class PipelineConfig:
    """A loaded, validated pipeline config.

    Attributes
    ----------
    pipeline : PipelineSection
    params : dict of str to StageParams
        Every stage's parameters, by stage name.
    path : Path or None
        The file it came from.
    executor : ExecutorSection
        Where the items run (not part of any key or manifest).
    taxonomy : Taxonomy
        The categories, parts and tasks the stages label with (``[pipeline] taxonomy``; Table I by default).
    """

    pipeline: PipelineSection
    params: dict[str, StageParams]
    path: Path | None = None
    executor: ExecutorSection = field(default_factory=ExecutorSection)
    taxonomy: Taxonomy = TABLE1


_VARIABLE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


def expand_variables(text: str) -> str:
    """Replace ``${NAME}`` and ``${NAME:-default}`` from the environment.

    Raises
    ------
    ConfigError
        If a variable without a default is not set.
    """

    def replace(match: re.Match[str]) -> str:
        name, default = match.group(1), match.group(2)
        value = os.environ.get(name)
        if value:
            return value
        if default is not None:
            return default
        raise ConfigError(f"environment variable {name} is not set and has no default (${{{name}:-...}})")

    return _VARIABLE.sub(replace, text)


def parse_override(text: str) -> tuple[str, str, Any]:
    """Split ``section.key=value`` into its parts, reading the value as TOML.

    Raises
    ------
    ConfigError
        If the text is not of that form.
    """
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(f"override {text!r} is not of the form section.key=value")
    dotted, raw = text.split("=", 1)
    section, key = dotted.strip().split(".", 1)
    try:
        value = tomllib.loads(f"value = {raw.strip()}")["value"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return section, key, value


def _expand(value: Any) -> Any:
    if isinstance(value, str):
        return expand_variables(value)
    if isinstance(value, list):
        return [_expand(item) for item in value]
    if isinstance(value, dict):
        return {key: _expand(item) for key, item in value.items()}
    return value


def _describe_error(
    origin: str, section: str, error: ValidationError, model: type[BaseModel], overrides: Mapping[str, str]
) -> str:
    """One line per problem: where it came from (the file or the override), ``[section] key = value``, the rule.

    Parameters
    ----------
    overrides : mapping of key to the override text that set it
        A problem with such a key blames the override, not the file.
    """
    lines = []
    for problem in error.errors():
        location = [str(part) for part in problem["loc"]]
        source = f"override {overrides[location[0]]!r}" if location and location[0] in overrides else origin
        message = problem["msg"].removeprefix("Value error, ")
        if problem["type"] == "extra_forbidden":
            message = f"unknown key; allowed keys: {', '.join(_group_model(model, location[:-1]).model_fields)}"
        if location:
            lines.append(f"{source}: [{section}] {'.'.join(location)} = {problem.get('input')!r}: {message}")
        else:  # a rule across keys: blame the file and every override of the section
            source += "".join(f", override {text!r}" for text in overrides.values())
            lines.append(f"{source}: [{section}]: {message}")
    return "\n".join(lines)


def _group_model(model: type[BaseModel], location: Sequence[str]) -> type[BaseModel]:
    """The model of the parameter group at ``location`` inside ``model`` (``["split"]``: ``[scenes.split]``)."""
    for part in location:
        info = model.model_fields.get(part)
        if info is None or not (isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel)):
            break
        model = info.annotation
    return model


def _validate(
    model: type[_Model], values: Mapping[str, Any], origin: str, section: str, overrides: Mapping[str, str]
) -> _Model:
    """Validate one section strictly: no string or boolean for a number, no number for a string.

    The values are validated as JSON, where pydantic's strict mode still
    takes an integer for a float and a list for a tuple (TOML has no tuples).

    Raises
    ------
    ConfigError
    """
    try:
        text = json.dumps(dict(values), default=str)
    except ValueError as error:  # a circular or otherwise unwritable value
        raise ConfigError(f"{origin}: [{section}]: {error}") from error
    try:
        return model.model_validate_json(text, strict=True)
    except ValidationError as error:
        raise ConfigError(_describe_error(origin, section, error, model, overrides)) from error


def build_config(
    document: Mapping[str, Any],
    stage_params: Mapping[str, type[StageParams]],
    *,
    origin: str = "<config>",
    base_dir: Path | None = None,
    overrides: Sequence[str] = (),
) -> PipelineConfig:
    """Validate a config document.

    Parameters
    ----------
    document : mapping
        The parsed TOML.
    stage_params : mapping of stage name to its Params class
    origin : str
        Named in errors (the file path).
    base_dir : Path, optional
        Folder that relative location paths are resolved against.
    overrides : sequence of str
        ``section.key=value`` strings applied on top of the document.

    Raises
    ------
    ConfigError
    """
    sections: dict[str, dict[str, Any]] = {
        name: dict(value) for name, value in document.items() if isinstance(value, dict)
    }
    loose = [name for name, value in document.items() if not isinstance(value, dict)]
    if loose:
        raise ConfigError(f"{origin}: top-level key(s) {loose} must sit inside a [section]")
    allowed = {"pipeline", "executor", *stage_params}
    overridden: dict[str, dict[str, str]] = {}
    for override in overrides:
        section, key, value = parse_override(override)
        if section not in allowed:
            raise ConfigError(f"override {override!r}: unknown section [{section}]; allowed: {sorted(allowed)}")
        *groups, last = key.split(".")
        target = sections.setdefault(section, {})
        for group in groups:  # section.group.key=value sets one key of a parameter group ([scenes.split])
            target[group] = dict(target[group]) if isinstance(target.get(group), dict) else {}
            target = target[group]
        target[last] = value
        overridden.setdefault(section, {})[groups[0] if groups else key] = override
    unknown = sorted(set(sections) - allowed)
    if unknown:
        raise ConfigError(f"{origin}: unknown section(s) {unknown}; allowed: {sorted(allowed)}")
    sections = {name: _expand(values) for name, values in sections.items()}

    pipeline_values = sections.get("pipeline", {})
    pipeline_values.setdefault("name", Path(origin).stem if origin != "<config>" else "pipeline")
    pipeline = _validate(PipelineSection, pipeline_values, origin, "pipeline", overridden.get("pipeline", {}))
    executor = _validate(
        ExecutorSection, sections.get("executor", {}), origin, "executor", overridden.get("executor", {})
    )

    taxonomy = _pipeline_taxonomy(pipeline.taxonomy, origin, base_dir)
    if pipeline.taxonomy and base_dir is not None:  # a config written out (config_to_toml) names the same file
        pipeline = pipeline.model_copy(update={"taxonomy": str((base_dir / pipeline.taxonomy).resolve())})
    params: dict[str, StageParams] = {}
    for name, params_class in stage_params.items():
        values = dict(sections.get(name, {}))
        for field_name, info in params_class.model_fields.items():
            extra = info.json_schema_extra
            is_location = isinstance(extra, dict) and extra.get("location")
            if is_location and base_dir is not None and isinstance(values.get(field_name), str):
                raw = values[field_name]
                if raw and not Path(raw).is_absolute():
                    values[field_name] = str((base_dir / raw).resolve())
        params[name] = _validate(params_class, values, origin, name, overridden.get(name, {}))
    mistakes = [f"{origin}: [{name}] {mistake}" for name, section in params.items()
                for mistake in section.taxonomy_mistakes(taxonomy)]
    if mistakes:
        raise ConfigError("\n".join(mistakes))
    return PipelineConfig(pipeline, params, Path(origin) if origin != "<config>" else None, executor, taxonomy)


def _pipeline_taxonomy(path: str, origin: str, base_dir: Path | None) -> Taxonomy:
    """The taxonomy ``[pipeline] taxonomy`` names (relative to ``base_dir``), Table I when empty.

    Raises
    ------
    ConfigError
        If the file is not there, has mistakes (a line each) or does not extend Table I.
    """
    if not path:
        return TABLE1
    file = Path(path) if Path(path).is_absolute() or base_dir is None else base_dir / path
    try:
        taxonomy = read_taxonomy(file)
    except FileNotFoundError as error:
        raise ConfigError(f"{origin}: [pipeline] taxonomy = {path!r}: {error}") from error
    except TaxonomyError as error:
        raise ConfigError(str(error)) from error
    if not taxonomy.extends_table1:
        raise ConfigError(f"{origin}: [pipeline] taxonomy = {path!r}: {file} does not extend Table I; the "
                          'generator labels Table I\'s tools as Table I does: give the file extends = "table1" '
                          "and list only what it adds (docs/taxonomy.md)")
    return taxonomy


#: The largest pipeline config read, bytes (a config is a few kB; more is a file given by mistake).
MAX_CONFIG_BYTES = 16 * 2**20
#: The largest input file (mesh, sidecar, annotation) read by default, bytes; ``OSGD_MAX_INPUT_BYTES`` overrides it.
DEFAULT_MAX_INPUT_BYTES = 2 * 2**30

_FILE_KINDS = (
    (stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
)


def max_input_bytes() -> int:
    """The size limit of an input file: ``OSGD_MAX_INPUT_BYTES`` (bytes, > 0), else :data:`DEFAULT_MAX_INPUT_BYTES`."""
    try:
        value = int(os.environ.get("OSGD_MAX_INPUT_BYTES", DEFAULT_MAX_INPUT_BYTES))
    except ValueError:
        return DEFAULT_MAX_INPUT_BYTES
    return value if value > 0 else DEFAULT_MAX_INPUT_BYTES


def _size_text(size: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.0f} {unit}" if unit == "bytes" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{size:.1f} GiB"


def _stat_problem(path: Path, error: OSError) -> str:
    """Why ``os.stat`` failed on a path: a symbolic link loop, a broken link, a missing file, no permission."""
    if error.errno == errno.ELOOP:
        return "a symbolic link loop (too many levels of symbolic links)"
    if path.is_symlink():
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"a broken symbolic link (to {target!r}, which cannot be reached: {error.strerror or error})"
    return str(error.strerror or error)


def file_problem(path: str | os.PathLike[str], max_bytes: int | None = None) -> str | None:
    """Why ``path`` cannot be read as an input file; None when it is a readable regular file of a bounded size.

    Reads nothing: only ``stat`` and ``access``, so a FIFO or a device is never opened (opening a FIFO blocks).

    Parameters
    ----------
    max_bytes : int, optional
        The size limit; default :func:`max_input_bytes`.
    """
    path = Path(path)
    limit = max_input_bytes() if max_bytes is None else max_bytes
    try:
        info = os.stat(path)
    except OSError as error:
        return _stat_problem(path, error)
    for test, kind in _FILE_KINDS:
        if test(info.st_mode):
            return f"{kind}, not a regular file"
    if not stat.S_ISREG(info.st_mode):
        return "not a regular file"
    if info.st_size > limit:
        return f"{_size_text(info.st_size)}, more than the {_size_text(limit)} an input file may have"
    if not os.access(path, os.R_OK):
        return "permission denied (not readable)"
    return None


def read_input_file(path: str | os.PathLike[str], max_bytes: int | None = None) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (default :func:`max_input_bytes`).

    Raises
    ------
    InputError
        Naming the file: not there, not a regular file (a FIFO, a device, a folder), too big, unreadable.
    """
    path = Path(path)
    limit = max_input_bytes() if max_bytes is None else max_bytes
    problem = file_problem(path, limit)
    if problem is not None:
        raise InputError(path, problem)
    try:
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as error:
        raise InputError(path, str(error.strerror or error)) from error
    if len(data) > limit:  # it grew since the check
        raise InputError(path, f"more than the {_size_text(limit)} an input file may have")
    return data


def load_config(
    path: str | os.PathLike[str],
    stage_params: Mapping[str, type[StageParams]],
    overrides: Sequence[str] = (),
) -> PipelineConfig:
    """Read and validate a pipeline TOML file.

    Only a regular file of at most :data:`MAX_CONFIG_BYTES` is read (not
    ``/dev/zero``, a FIFO or a huge file given by mistake).

    Raises
    ------
    ConfigError
        If the file is missing, is no regular file of a bounded size, is not
        valid UTF-8 TOML, or holds a bad value.
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise ConfigError(f"{path}: no such pipeline config")
    try:
        data = read_input_file(path, MAX_CONFIG_BYTES)
    except InputError as error:
        raise ConfigError(f"{path}: cannot be read as a pipeline config: {error.cause}") from error
    try:
        document = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not a pipeline config: not UTF-8 text ({error.reason} at byte "
                          f"{error.start}); a config is a TOML file such as pipelines/default.toml") from error
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from error
    return build_config(
        document, stage_params, origin=str(path), base_dir=path.resolve().parent, overrides=overrides
    )


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        inner = ", ".join(f"{json.dumps(str(key))} = {_toml_value(item)}" for key, item in value.items())
        return "{ " + inner + " }" if inner else "{}"
    if value is None:
        raise ConfigError("TOML has no null; leave the key out instead")
    raise ConfigError(f"cannot write {value!r} as TOML")


def config_to_toml(config: PipelineConfig) -> str:
    """Every parameter of every stage, and the executor section, as a commented TOML document.

    Each key is preceded by its description; keys that are ``None`` (unset
    optional values) are written as comments. Loading the text back with
    :func:`build_config` gives an equal config.
    """
    lines = ["[pipeline]", f"name = {_toml_value(config.pipeline.name)}", f"seed = {config.pipeline.seed}"]
    if config.pipeline.taxonomy:
        lines.append(f"taxonomy = {_toml_value(config.pipeline.taxonomy)}")
    for section, values in (*config.params.items(), ("executor", config.executor)):
        lines += ["", f"[{section}]", *_section_lines(values)]
    return "\n".join(lines) + "\n"


def _section_lines(section: BaseModel) -> list[str]:
    """The ``key = value`` lines of one section, each after its description."""
    lines = []
    values = section.model_dump(mode="json")
    for field_name, info in type(section).model_fields.items():
        if info.description:
            lines.append(f"# {info.description}")
        value = values[field_name]
        if value is None:
            lines.append(f"# {field_name} = (unset)")
        else:
            lines.append(f"{field_name} = {_toml_value(value)}")
    return lines

"""Config dataclasses as flags and TOML files (tools.config), on toy configs defined here."""

from __future__ import annotations

import argparse
import dataclasses
import doctest
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

import tools.config
from tools.config import ConfigError, add_config_flags, dump_config, field_docs, load_config, positive


def parse_robots(text: str) -> tuple[int, ...]:
    """'0-2,5' -> (0, 1, 2, 5)."""
    robots: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        robots.extend(range(int(lo), int(hi or lo) + 1))
    return tuple(robots)


@dataclass(frozen=True, slots=True)
class Fit:
    n_cycles: int = 250
    """ENNC cycles per fit."""
    max_patterns: int | None = 30_000
    """Tuples per action per fit (None: all)."""
    standardize: bool = True
    """Fit ENNC on states scaled to unit variance,
    on 100% of them."""
    targets: Literal["max", "mean"] = "max"
    """How q is computed."""

    def __post_init__(self) -> None:
        if self.n_cycles < 1:
            raise ValueError(f"n_cycles must be at least 1, got {self.n_cycles}")


@dataclass(frozen=True, slots=True)
class Toy:
    learner_id: str = "learner"
    """Learner id."""
    store_capacity: int = 1_000_000
    """Tuples kept; the oldest are overwritten beyond it."""
    gamma: float = 0.9
    duration: float | None = None
    """Stop after this many seconds (None: until stopped)."""
    run_dir: Path = Path("runs/toy")
    """Folder of the run."""
    weights: tuple[float, ...] = (1.0, 0.5)
    """Weights of the terms."""
    fit: Fit = field(default_factory=lambda: Fit(n_cycles=100))
    learn: tuple[int, ...] | None = field(default=None, metadata={"parse": parse_robots})
    """Robots this actor learns, e.g. 0-4,7 (default: all)."""
    label: str | None = None
    """Free-form label."""

    def __post_init__(self) -> None:
        if self.store_capacity < 1:
            raise ValueError(f"store_capacity must be at least 1, got {self.store_capacity}")


@dataclass(frozen=True, slots=True)
class Deep:
    toy: Toy = field(default_factory=Toy)
    seed: int = 0
    """Seed of everything."""


@dataclass(frozen=True)
class Derived(Fit):
    extra: int = 1
    """A field of the subclass."""


def parser_for(cls: type, **kwargs: object) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ennc-ql toy")
    add_config_flags(parser, cls, **kwargs)  # type: ignore[arg-type]
    return parser


def help_of(parser: argparse.ArgumentParser) -> str:
    return " ".join(parser.format_help().split())  # help lines wrap wherever the terminal width says


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "toy.toml"
    path.write_text(text)
    return path


def usage_error(parser: argparse.ArgumentParser, argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    with pytest.raises(SystemExit) as exit_info:
        parser.parse_args(argv)
    assert exit_info.value.code == 2
    return capsys.readouterr().err


# --- docstrings and help ---


def test_field_docs_reads_attribute_docstrings_and_bases() -> None:
    docs = field_docs(Toy)
    assert docs["store_capacity"] == "Tuples kept; the oldest are overwritten beyond it."
    assert "gamma" not in docs  # no docstring follows it
    assert "fit" not in docs
    derived = field_docs(Derived)
    assert derived["extra"] == "A field of the subclass."
    assert derived["standardize"] == "Fit ENNC on states scaled to unit variance, on 100% of them."


def test_help_shows_docstring_and_effective_default() -> None:
    text = help_of(parser_for(Toy))
    assert "--store-capacity INT Tuples kept; the oldest are overwritten beyond it. (default: 1000000)" in text
    assert "--fit-n-cycles INT ENNC cycles per fit. (default: 100)" in text  # the factory's, not the class's 250
    assert "--duration FLOAT|none Stop after this many seconds (None: until stopped). (default: none)" in text
    assert "--fit-standardize, --no-fit-standardize" in text
    assert "on 100% of them. (default: True)" in text
    assert "--fit-targets {max,mean} How q is computed. (default: max)" in text
    assert "--weights FLOAT,... Weights of the terms. (default: 1.0,0.5)" in text
    assert "--gamma FLOAT (default: 0.9)" in text


def test_help_shows_presets() -> None:
    text = help_of(parser_for(Toy, defaults={"store_capacity": 400_000, "fit.max_patterns": 20_000}))
    assert "overwritten beyond it. (default: 400000)" in text
    assert "(default: 1000000)" not in text
    assert "(None: all). (default: 20000)" in text


def test_unknown_exclude_or_preset_path_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="did you mean 'store_capacity'"):
        parser_for(Toy, defaults={"store_capacty": 1})
    with pytest.raises(ValueError, match="no field 'nope'"):
        parser_for(Toy, exclude=("nope",))


def test_unsupported_type_without_parse_hook_is_rejected_up_front() -> None:
    @dataclass(frozen=True)
    class Bad:
        mapping: dict[str, int] = field(default_factory=dict)

    with pytest.raises(TypeError, match="unsupported config field type"):
        parser_for(Bad)


# --- flags ---


def test_flags_parse_to_field_types_and_only_given_ones_are_set() -> None:
    argv = ["--store-capacity", "5", "--duration", "60", "--run-dir", "a/b", "--weights", "1, 2.5"]
    argv += ["--learn", "0-2,5", "--fit-targets", "mean", "--fit-max-patterns", "none", "--label", "x"]
    args = parser_for(Toy).parse_args(argv)
    given = vars(args)
    assert given == {
        "store_capacity": 5,
        "duration": 60.0,
        "run_dir": Path("a/b"),
        "weights": (1.0, 2.5),
        "learn": (0, 1, 2, 5),
        "fit.targets": "mean",
        "fit.max_patterns": None,
        "label": "x",
    }
    assert type(given["duration"]) is float
    config = load_config(Toy, args=args)
    assert config.fit == Fit(n_cycles=100, max_patterns=None, targets="mean")
    assert config.gamma == 0.9 and config.learner_id == "learner"


def test_nested_flags_two_levels_deep() -> None:
    args = parser_for(Deep).parse_args(["--toy-fit-n-cycles", "7", "--toy-store-capacity", "9", "--seed", "3"])
    assert load_config(Deep, args=args) == Deep(toy=Toy(store_capacity=9, fit=Fit(n_cycles=7)), seed=3)


@pytest.mark.parametrize(("argv", "expected"), [([], True), (["--no-fit-standardize"], False)])
def test_bool_flags_both_ways(argv: list[str], expected: bool) -> None:
    parser = parser_for(Toy, defaults={"fit.standardize": not expected})
    flipped = ["--fit-standardize"] if not expected else ["--no-fit-standardize"]
    assert load_config(Toy, args=parser.parse_args(argv), defaults={"fit.standardize": expected}).fit.standardize is (
        expected
    )
    assert load_config(Toy, args=parser.parse_args(flipped)).fit.standardize is (not expected)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--store-capacity", "x"], "argument --store-capacity: expected an integer, got 'x'"),
        (["--store-capacity", "1.5"], "argument --store-capacity: expected an integer, got '1.5'"),
        (["--gamma", "high"], "argument --gamma: expected a finite number, got 'high'"),
        (["--fit-targets", "median"], "argument --fit-targets: invalid choice: 'median' (choose from max, mean)"),
        (["--fit-n-cycles", "none"], "argument --fit-n-cycles: expected an integer, got 'none'"),
        (["--weights", "1,a"], "argument --weights: expected a finite number, got 'a'"),
        (["--learn", "a-b"], "argument --learn: invalid literal for int()"),
    ],
)
def test_bad_flag_values_give_a_usage_error_naming_the_flag(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    err = usage_error(parser_for(Toy), argv, capsys)
    assert err.startswith("usage: ennc-ql toy")
    assert f"ennc-ql toy: error: {message}" in err


def test_excluded_fields_get_no_flag(capsys: pytest.CaptureFixture[str]) -> None:
    parser = parser_for(Toy, exclude=("learner_id", "fit"))
    text = help_of(parser)
    assert "--learner-id" not in text and "--fit-" not in text
    assert "--store-capacity" in text
    assert "unrecognized arguments: --fit-n-cycles" in usage_error(parser, ["--fit-n-cycles", "3"], capsys)


# --- precedence and errors ---


def test_precedence_defaults_presets_file_flags(tmp_path: Path) -> None:
    presets = {"store_capacity": 400_000, "fit.n_cycles": 50, "learner_id": "preset"}
    file = write(tmp_path, 'learner_id = "file"\n[fit]\nn_cycles = 20\n')
    args = parser_for(Toy, defaults=presets).parse_args(["--learner-id", "flag"])
    config = load_config(Toy, file=file, args=args, defaults=presets)
    assert config.gamma == 0.9  # dataclass default
    assert config.store_capacity == 400_000  # preset over default
    assert config.fit.n_cycles == 20  # file over preset
    assert config.learner_id == "flag"  # flag over file
    assert config.fit.max_patterns == 30_000  # the rest of the nested default kept
    assert load_config(Toy, defaults=presets).fit.n_cycles == 50


def test_file_values_are_converted(tmp_path: Path) -> None:
    file = write(
        tmp_path,
        'gamma = 1\nrun_dir = "x/y"\nweights = [1, 2.5]\nlearn = "0-1,4"\n[fit]\nmax_patterns = "none"\n',
    )
    config = load_config(Toy, file=file)
    assert config.gamma == 1.0 and type(config.gamma) is float
    assert config.run_dir == Path("x/y")
    assert config.weights == (1.0, 2.5)
    assert config.learn == (0, 1, 4)  # a string goes through the parse hook
    assert config.fit.max_patterns is None
    assert load_config(Toy, file=write(tmp_path, "learn = [3, 1]\n")).learn == (3, 1)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("store_capacty = 5\n", "unknown key 'store_capacty' (did you mean 'store_capacity'?)"),
        ("[fit]\nn_cyles = 5\n", "unknown key 'fit.n_cyles' (did you mean 'fit.n_cycles'?)"),
        ("zzz = 5\n", "unknown key 'zzz'"),
    ],
)
def test_unknown_file_key_is_named_with_a_suggestion(tmp_path: Path, text: str, message: str) -> None:
    file = write(tmp_path, text)
    with pytest.raises(ConfigError) as error:
        load_config(Toy, file=file)
    assert str(error.value) == f"{file}: {message}"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('store_capacity = "big"\n', "key 'store_capacity' must be an integer, got 'big'"),
        ("store_capacity = true\n", "key 'store_capacity' must be an integer, got True"),
        ("duration = true\n", "key 'duration' must be a finite number or none, got True"),
        ("weights = [1, 'a']\n", "key 'weights' must be an array, each a finite number, got [1, 'a']"),
        ("fit = 3\n", "key 'fit' must be a table ([fit]), got 3"),
        ('[fit]\ntargets = "median"\n', "key 'fit.targets' must be one of 'max', 'mean', got 'median'"),
        ("[fit]\nstandardize = 1\n", "key 'fit.standardize' must be true or false, got 1"),
        ('learn = "x"\n', "key 'learn' is invalid (invalid literal for int() with base 10: 'x'), got 'x'"),
    ],
)
def test_wrong_file_type_is_named(tmp_path: Path, text: str, message: str) -> None:
    file = write(tmp_path, text)
    with pytest.raises(ConfigError) as error:
        load_config(Toy, file=file)
    assert str(error.value) == f"{file}: {message}"


def test_post_init_value_error_becomes_config_error(tmp_path: Path) -> None:
    args = parser_for(Toy).parse_args(["--store-capacity", "0"])
    with pytest.raises(ConfigError, match=r"^store_capacity must be at least 1, got 0$"):
        load_config(Toy, args=args)
    with pytest.raises(ConfigError, match=r"^fit: n_cycles must be at least 1, got 0$"):
        load_config(Toy, file=write(tmp_path, "[fit]\nn_cycles = 0\n"))


def test_unreadable_or_invalid_file_and_bad_presets(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(Toy, file=tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match=r"toy\.toml: .*line 1"):
        load_config(Toy, file=write(tmp_path, "store_capacity ==\n"))
    with pytest.raises(ConfigError, match="unknown preset key 'gama' \\(did you mean 'gamma'\\?\\)"):
        load_config(Toy, defaults={"gama": 0.5})
    with pytest.raises(ConfigError, match="preset key 'gamma' must be a finite number"):
        load_config(Toy, defaults={"gamma": "high"})


def test_missing_required_field() -> None:
    @dataclass(frozen=True)
    class Needs:
        run_dir: Path
        """Folder of the run."""

    with pytest.raises(ConfigError, match=r"missing required key 'run_dir' \(give --run-dir\)"):
        load_config(Needs)
    assert "(required)" in help_of(parser_for(Needs))
    assert load_config(Needs, args=parser_for(Needs).parse_args(["--run-dir", "r"])) == Needs(Path("r"))


# --- dump ---


ROUND_TRIPS = [
    Toy(),
    Toy(
        learner_id="a",
        store_capacity=7,
        gamma=0.25,
        duration=60.5,
        run_dir=Path("/tmp/x"),
        weights=(),
        fit=Fit(n_cycles=3, max_patterns=None, standardize=False, targets="mean"),
        learn=(0, 2),
        label="",
    ),
]


@pytest.mark.parametrize("config", ROUND_TRIPS)
def test_dump_load_round_trip(tmp_path: Path, config: Toy) -> None:
    text = dump_config(config)
    assert load_config(Toy, file=write(tmp_path, text)) == config


def test_dump_omits_none_only_where_the_default_is_none() -> None:
    text = dump_config(dataclasses.replace(Toy(), fit=Fit(max_patterns=None)))
    keys = {line.split(" = ")[0] for line in text.splitlines() if " = " in line}
    assert not keys & {"duration", "label", "learn"}  # None by default
    assert {"learner_id", "store_capacity", "max_patterns"} <= keys
    assert 'max_patterns = "none"' in text  # default 30_000: leaving it out would bring that back
    assert text.index("[fit]") > text.index("store_capacity")
    assert 'run_dir = "runs/toy"' in text and "weights = [\n    1.0,\n    0.5,\n]" in text


def test_dump_nested_tables(tmp_path: Path) -> None:
    config = Deep(toy=Toy(fit=Fit(n_cycles=9)), seed=4)
    text = dump_config(config)
    assert "[toy.fit]\nn_cycles = 9\n" in text
    assert load_config(Deep, file=write(tmp_path, text)) == config


# --- positive ---


@pytest.mark.parametrize("text", ["0", "-1", "x", "1.5"])
def test_positive_int_rejects(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=f"^expected a positive integer, got '{text}'$"):
        positive(int)(text)


@pytest.mark.parametrize("text", ["0", "-0.5", "x", "nan", "inf"])
def test_positive_float_rejects(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=f"^expected a positive finite number, got '{text}'$"):
        positive(float)(text)


def test_positive_accepts_and_reads_as_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert positive(int)("12") == 12 and positive(float)("0.25") == 0.25
    parser = argparse.ArgumentParser(prog="p")
    parser.add_argument("--trials", type=positive(int))
    assert "p: error: argument --trials: expected a positive integer, got '-5'" in usage_error(
        parser, ["--trials", "-5"], capsys
    )


def test_module_docstring_example_runs() -> None:
    result = doctest.testmod(tools.config)
    assert result.attempted >= 5 and result.failed == 0

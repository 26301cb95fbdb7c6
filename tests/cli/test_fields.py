"""The flags of every command come from its config dataclass's fields (``vp2.cli._fields``)."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from vp2 import cli
from vp2.cli._fields import NOT_A_FLAG, Flag, add_flags, build, dest


@dataclasses.dataclass(frozen=True)
class Inner:
    size: int = 3
    rate: float = 0.5
    hidden: str = "kept"


@dataclasses.dataclass(frozen=True)
class Outer:
    name: str
    count: int | None = None
    seeds: tuple[int, ...] = (0, 1)
    fast: bool = False
    pictures: bool = True
    inner: Inner = dataclasses.field(default_factory=Inner)
    extra: str = "x"


FLAGS = {
    "name": Flag(required=True, help="its name"),
    "count": Flag(metavar="N", group="numbers"),
    "seeds": Flag(group="numbers"),
    "fast": Flag(),
    "pictures": Flag("--no-pictures", negate=True),
    "inner.size": Flag(group="numbers"),
    "inner.rate": Flag("--learning-rate"),
    "inner.hidden": NOT_A_FLAG,
    "extra": NOT_A_FLAG,
    "verbose_output": Flag(cli_only=True, action="store_true"),
}


def _parser(flags=FLAGS) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="t")
    add_flags(p, Outer, flags)
    return p


def test_flags_take_type_default_nargs_and_action_from_the_field():
    args = _parser().parse_args(["--name", "a"])
    assert build(Outer, args, FLAGS) == Outer(name="a")
    args = _parser().parse_args(["--name", "a", "--count", "4", "--seeds", "5", "6", "--fast",
                                 "--no-pictures", "--size", "9", "--learning-rate", "0.1",
                                 "--verbose-output"])
    assert args.verbose_output and dest("inner.rate", FLAGS["inner.rate"]) == "learning_rate"
    assert build(Outer, args, FLAGS, extra="y") == Outer(
        name="a", count=4, seeds=(5, 6), fast=True, pictures=False,
        inner=Inner(size=9, rate=0.1), extra="y")
    # A value given to build replaces the flag's; a nested dataclass given whole, its flags'.
    assert build(Outer, args, FLAGS, count=1, inner=Inner()).inner == Inner()
    help_text = _parser().format_help()
    assert "numbers:\n  --count N\n  --seeds SEEDS [SEEDS ...]\n  --size SIZE" in help_text
    assert "--hidden" not in help_text and "--extra" not in help_text


def test_every_field_needs_an_entry():
    with pytest.raises(ValueError, match=r"Outer field\(s\) \['extra'\] have no entry"):
        _parser({k: v for k, v in FLAGS.items() if k != "extra"})
    with pytest.raises(ValueError, match=r"\['inner.rate'\] have no entry"):
        _parser({k: v for k, v in FLAGS.items() if k != "inner.rate"})
    with pytest.raises(ValueError, match=r"Outer has no field\(s\) \['colour'\]"):
        _parser({**FLAGS, "colour": Flag()})
    with pytest.raises(ValueError, match="needs negate=True"):
        _parser({**FLAGS, "pictures": Flag()})
    # The whole nested dataclass without flags: one entry.
    flags = {k: v for k, v in FLAGS.items() if not k.startswith("inner.")} | {"inner": NOT_A_FLAG}
    assert build(Outer, _parser(flags).parse_args(["--name", "a"]), flags).inner == Inner()


def test_each_command_with_a_config_has_an_entry_per_field():
    """A field added to a command's config without an entry fails here (and when ``vp2``
    builds its parser)."""
    from vp2.benchmark.main_job import MainJobConfig
    from vp2.classifiers.train import ClassifierTrainConfig
    from vp2.cli import collect, main_job, run, train, train_classifier
    from vp2.data.collect import CollectionConfig
    from vp2.planning.planner import PlannerConfig
    from vp2.run.config import RunConfig
    from vp2.training.config import TrainConfig

    def names(cls, prefix=""):
        out = set()
        for f in dataclasses.fields(cls):
            if f.name == "planner" and cls is RunConfig:
                out |= names(PlannerConfig, "planner.")
            else:
                out.add(prefix + f.name)
        return out

    for cls, flags in [(RunConfig, run.FLAGS), (MainJobConfig, main_job.FLAGS),
                       (CollectionConfig, collect.FLAGS), (TrainConfig, train._flags()),  # noqa: SLF001
                       (ClassifierTrainConfig, train_classifier.FLAGS)]:
        assert names(cls) <= set(flags), cls.__name__
        assert all(f and f.cli_only for k, f in flags.items() if k not in names(cls))
    cli.build_parser()

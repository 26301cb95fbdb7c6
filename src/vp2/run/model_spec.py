"""The model to benchmark from a string (``--model``): a plugin, a YAML file or a checkpoint.

A model spec is one of

* a built-in name: ``simulator`` (alias ``oracle``), ``repeat_last_frame``;
* ``NAME:CHECKPOINT`` with a registered model name, e.g. ``svg_prime:runs/svg`` (a trained
  vp2 model, :func:`vp2.models.load_model_spec`);
* ``zoo:NAME``: a model of the zoo, e.g. ``zoo:svg_prime-tiny-robodesk`` (its card's family and
  checkpoint, the checkpoint checked against the card's sha256; :mod:`vp2.models.zoo`);
* ``package.module:factory``: any importable callable returning a
  :class:`vp2.models.base.VideoPredictionModel`, called with the run's model arguments;
* a ``.yaml``/``.yml`` file whose mapping has a ``_target_`` (``package.module:factory`` or
  ``package.module.factory``) and the factory's keyword arguments; nested mappings with their
  own ``_target_`` are built first (as Hydra's ``instantiate``). Run arguments override the
  file's;
* ``ensemble(SPEC,SPEC,...)``: two or more of the forms above (not the simulator, not another
  ensemble), comma-separated, planned with the ensemble cost of SPEC §5
  (:class:`vp2.models.ensemble.EnsembleModel`); every member gets the run's model arguments.
  No other form holds a ``(``, so it cannot be read as one of them.

A factory may also declare any of the parameters ``env`` (``"robodesk"``/``"tabletop"``),
``action_dim`` and ``device``; the runner fills those it does not get explicitly, so one spec
serves both environments (the runner builds one model per environment).

Modules are imported with the current directory on the import path (appended, so an installed
package of the same name wins), so ``--model mymodule:make_model`` works from the folder of
``mymodule.py``. :meth:`ModelSpec.parse` is the one place a string is read as a spec (the
functions below take the string or the parsed :class:`ModelSpec`); :func:`check_spec` checks
one before any trial (a checkpoint is read, safely: ``torch.load(weights_only=True)``; a zoo
checkpoint's sha256 is compared with its card's);
:func:`resolve_model` is the one place a spec becomes a model: it returns it wrapped by
:func:`vp2.models.contract.checked` (checked calls, the interface's defaults).
:func:`parse_model_args` reads the model arguments of the command line (``--model-arg``).

Importing this module does not load torch; parsing a spec with a colon does (it asks the model
registry whether the part before the colon names a model).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import yaml

from vp2.utils.kv import parse_key_values, yaml_value

if TYPE_CHECKING:
    import torch

    from vp2.models.registry import CheckpointSpec
    from vp2.models.zoo import ZooCard

#: Built-in model names and their factories.
BUILTIN_MODELS: dict[str, str] = {
    "simulator": "vp2.models.simulator:SimulatorModel",
    "oracle": "vp2.models.simulator:SimulatorModel",
    "repeat_last_frame": "vp2.models.baselines:RepeatLastFrame",
}
#: Keyword arguments the runner supplies to factories that declare them.
CONTEXT_ARGS: tuple[str, ...] = ("env", "action_dim", "device")
#: Where the model interface is documented (named in the messages of model failures).
MODEL_DOCS = 'docs/evaluation.md, "Plugins"'


class PluginError(ValueError):
    """A model spec that cannot be resolved or built, with the reason."""


def resolve_target(target: str) -> Callable[..., Any]:
    """Imports ``package.module:attr`` (or ``package.module.attr``; ``attr`` may be dotted).

    Raises:
        PluginError: naming the module or attribute that is missing.
    """
    if ":" in target:
        module_name, _, attr = target.partition(":")
    else:
        module_name, _, attr = target.rpartition(".")
    if not module_name or not attr:
        raise PluginError(f"target {target!r}: expected 'package.module:factory'")
    _add_cwd_to_path()
    try:
        obj: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise PluginError(
            f"target {target!r}: cannot import module {module_name!r} ({exc})"
        ) from exc
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise PluginError(
                f"target {target!r}: module {module_name!r} has no attribute {attr!r}"
            )
        obj = getattr(obj, part)
    if not callable(obj):
        raise PluginError(f"target {target!r} is not callable")
    return obj


def _add_cwd_to_path() -> None:
    """Lets ``mymodule:factory`` resolve from the folder of ``mymodule.py``, as ``python``
    would (a console script like ``vp2`` has its own folder on ``sys.path``, not the current
    one). Appended: an installed package of the same name still wins."""
    cwd = os.getcwd()
    if cwd not in sys.path and "" not in sys.path:
        sys.path.append(cwd)


def instantiate(node: Any) -> Any:
    """Builds every mapping with a ``_target_`` in ``node``, innermost first."""
    if isinstance(node, Mapping):
        built = {k: instantiate(v) for k, v in node.items() if k != "_target_"}
        if "_target_" in node:
            return resolve_target(str(node["_target_"]))(**built)
        return built
    if isinstance(node, list):
        return [instantiate(v) for v in node]
    return node


def read_yaml_spec(path: str | Path) -> dict[str, Any]:
    """A YAML model file as a mapping with a ``_target_``.

    Raises:
        PluginError: if the file is not a mapping with a ``_target_``.
    """
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise PluginError(f"{path}: cannot read the model file ({exc})") from exc
    if not isinstance(data, dict) or "_target_" not in data:
        raise PluginError(
            f"{path}: a model file must be a mapping with a `_target_` key "
            "(e.g. `_target_: mypkg.models:build`) and the factory's arguments"
        )
    return data


#: ``package.module:factory`` (``factory`` may be dotted: a class attribute).
_FACTORY = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")
SpecKind = Literal["builtin", "checkpoint", "zoo", "factory", "yaml", "ensemble"]
#: The prefix of a zoo entry (``vp2.models.zoo.ZOO_PREFIX``; kept here so that reading a spec
#: without a colon imports no torch).
ZOO_PREFIX = "zoo:"
#: How an ensemble spec begins: ``ensemble(SPEC,SPEC,...)``.
ENSEMBLE_PREFIX = "ensemble("


@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """A ``--model`` string, parsed once (:meth:`parse`): which of the six forms it is and
    what it names.

    Attributes:
        text: The string as given (what result records and messages show).
        kind: ``builtin``, ``checkpoint`` (``NAME:CHECKPOINT``), ``zoo`` (``zoo:NAME``),
            ``factory`` (``package.module:factory``), ``yaml`` or ``ensemble``.
        target: The factory to call, ``package.module:factory`` (``builtin``, ``factory``).
        path: The model file (``yaml``) or the checkpoint file or run directory
            (``checkpoint``, ``zoo``).
        checkpoint: The registered model and its checkpoint (``checkpoint``, ``zoo``).
        zoo: The zoo entry's card (``zoo``).
        members: The members' specs (``ensemble``).
    """

    text: str
    kind: SpecKind
    target: str | None = None
    path: Path | None = None
    checkpoint: CheckpointSpec | None = None
    zoo: ZooCard | None = dataclasses.field(default=None, compare=False)
    members: tuple[ModelSpec, ...] = ()

    def __str__(self) -> str:
        return self.text

    @classmethod
    def parse(cls, text: str) -> ModelSpec:
        """The spec a string is: a built-in name, else a ``.yaml``/``.yml`` file, else
        ``ensemble(...)`` (each member parsed), else ``zoo:NAME`` (its card is read), else
        ``NAME:CHECKPOINT`` if the part before the first colon is a registered model (both
        import the models, and torch), else ``package.module:factory``. Reads no other file.

        Raises:
            PluginError: none of these forms, or a zoo name the zoo does not have (for an
                ensemble: naming the member).
        """
        if text in BUILTIN_MODELS:
            return cls(text, "builtin", target=BUILTIN_MODELS[text])
        if text.endswith((".yaml", ".yml")):
            return cls(text, "yaml", path=Path(text))
        if text.startswith(ENSEMBLE_PREFIX):
            return cls._ensemble(text)
        if text.startswith(ZOO_PREFIX):
            return cls._zoo(text)
        names = "NAME:CHECKPOINT"
        if ":" in text:
            from vp2.models.registry import CheckpointSpec, model_names

            try:
                checkpoint = CheckpointSpec.match(text)
            except ValueError as err:
                raise PluginError(str(err)) from None
            if checkpoint is not None:
                return cls(text, "checkpoint", path=checkpoint.path, checkpoint=checkpoint)
            if _FACTORY.fullmatch(text):
                return cls(text, "factory", target=text)
            names = f"NAME:CHECKPOINT (NAME: {', '.join(model_names())})"
        raise PluginError(
            f"model {text!r}: expected a built-in name ({', '.join(BUILTIN_MODELS)}), "
            f"{names}, zoo:NAME, package.module:factory, a .yaml file or ensemble(SPEC,SPEC,...)"
        )

    @classmethod
    def _ensemble(cls, text: str) -> ModelSpec:
        """``ensemble(SPEC,SPEC,...)``: each member parsed (not yet checked)."""
        usage = "an ensemble is ensemble(SPEC,SPEC,...), e.g. ensemble(zoo:a,zoo:b)"
        if not text.endswith(")"):
            raise PluginError(f"model {text!r}: no closing ')'; {usage}")
        names = [name.strip() for name in text[len(ENSEMBLE_PREFIX) : -1].split(",")]
        if len(names) < 2 or not all(names):
            problem = f"member {names.index('') + 1} is empty" if not all(names) else "1 member"
            raise PluginError(f"model {text!r}: {problem}; {usage}")
        members = []
        for i, name in enumerate(names, 1):
            if name.startswith(ENSEMBLE_PREFIX) or BUILTIN_MODELS.get(name) == BUILTIN_MODELS[
                "simulator"
            ]:
                raise PluginError(f"ensemble member {i} of {text!r}, {name!r}: an ensemble member "
                                  "predicts from frames (not the simulator, not an ensemble)")
            try:
                members.append(cls.parse(name))
            except PluginError as err:
                raise PluginError(f"ensemble member {i} of {text!r}: {err}") from None
        return cls(text, "ensemble", members=tuple(members))

    @classmethod
    def _zoo(cls, text: str) -> ModelSpec:
        """``zoo:NAME``: the card's family and checkpoint (not yet checked against the card)."""
        from vp2.models.registry import CheckpointSpec
        from vp2.models.zoo import ZooError, get_card

        try:
            card = get_card(text.removeprefix(ZOO_PREFIX), verify=False)
        except ZooError as err:
            raise PluginError(f"model {text!r}: {err}") from None
        path = card.checkpoint_path
        return cls(text, "zoo", path=path, checkpoint=CheckpointSpec(card.family, path), zoo=card)

    def verify(self) -> None:
        """Checks a zoo entry's checkpoint against its card (nothing for other forms).

        Raises:
            PluginError: the checkpoint is missing or its sha256 is not the card's.
        """
        if self.zoo is None:
            return
        from vp2.models.zoo import ZooError

        try:
            self.zoo.verify()
        except ZooError as err:
            raise PluginError(f"model {self.text!r}: {err}") from None

    def check(self) -> None:
        """Resolves the spec without building the model (fails fast, before any trial): imports
        the factory, reads the YAML file, or reads the checkpoint (``weights_only``, on the CPU)
        and checks it holds the named model (a zoo entry's: after checking it against its card).
        An ensemble checks every member, then that its checkpoints agree on the environment
        and the interface sizes (:func:`vp2.models.ensemble.check_checkpoints_agree`).

        Raises:
            PluginError: naming the spec (an ensemble's member) and what is wrong, in one line.
        """
        if self.kind == "ensemble":
            from vp2.models.ensemble import EnsembleMismatch, check_checkpoints_agree

            for i, member in enumerate(self.members, 1):
                try:
                    member.check()
                except PluginError as err:
                    raise PluginError(f"ensemble member {i} of {self.text!r}: {err}") from None
            try:
                check_checkpoints_agree(
                    [(m.text, m.checkpoint.path) for m in self.members if m.checkpoint]
                )
            except EnsembleMismatch as err:
                raise PluginError(f"model {self.text!r}: {err}") from None
        elif self.kind == "yaml":
            resolve_target(str(read_yaml_spec(self.text)["_target_"]))
        elif self.checkpoint is not None:
            self.verify()
            try:
                self.checkpoint.check()
            except (FileNotFoundError, ValueError) as err:
                raise PluginError(f"model {self.text!r}: {err}") from err
        else:
            resolve_target(str(self.target))

    def build(
        self, args: Mapping[str, Any] | None = None, context: Mapping[str, Any] | None = None
    ) -> Any:
        """The object a built-in, factory or YAML spec names (see :func:`load_plugin`).

        Raises:
            PluginError: the spec cannot be resolved, or is a checkpoint (built by
                :func:`resolve_model`).
        """
        args = dict(args or {})
        if self.kind == "yaml":
            data = read_yaml_spec(self.text)
            target = str(data.pop("_target_"))
            args = {**instantiate(data), **args}
        elif self.checkpoint is not None:
            raise PluginError(f"model {self.text!r}: a checkpoint is loaded by resolve_model")
        else:
            target = str(self.target)
        factory = resolve_target(target)
        accepted = _accepted(factory)
        for key, value in (context or {}).items():
            if key in accepted and key not in args:
                args[key] = value
        return factory(**args)


def _parsed(spec: str | ModelSpec) -> ModelSpec:
    return spec if isinstance(spec, ModelSpec) else ModelSpec.parse(spec)


def describe_spec(spec: str | ModelSpec) -> str:
    """What kind of spec this is: ``builtin``, ``checkpoint``, ``zoo``, ``yaml`` or ``factory``.

    Raises:
        PluginError: none of these forms (see :meth:`ModelSpec.parse`).
    """
    return _parsed(spec).kind


def check_spec(spec: str | ModelSpec) -> None:
    """Resolves a spec without building anything (fails fast, before workers start): see
    :meth:`ModelSpec.check`.

    Raises:
        PluginError: if the factory cannot be imported, the file read, or the checkpoint is
            missing, is not a vp2 checkpoint of the named model or (``zoo:NAME``) is not the
            one its card describes.
    """
    _parsed(spec).check()


def _accepted(factory: Callable[..., Any]) -> set[str]:
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return set()
    return {
        name
        for name, p in params.items()
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }


def load_plugin(
    spec: str | ModelSpec,
    args: Mapping[str, Any] | None = None,
    context: Mapping[str, Any] | None = None,
) -> Any:
    """Builds the object a spec names.

    Args:
        spec: Built-in name, ``package.module:factory`` or a YAML file (see the module doc).
            ``NAME:CHECKPOINT`` and ``zoo:NAME`` specs are loaded by :func:`resolve_model` only.
        args: Keyword arguments for the factory (override a YAML file's).
        context: Arguments passed only if the factory declares a parameter of that name and
            ``args`` does not set it.

    Raises:
        PluginError: if the spec cannot be resolved.
    """
    return _parsed(spec).build(args, context)


def resolve_model(
    spec: str | ModelSpec,
    args: Mapping[str, Any] | None = None,
    *,
    env: str,
    action_dim: int,
    device: str | torch.device,
    check: bool = True,
) -> Any:
    """The model a spec names, for one environment, on ``device``.

    ``torch.nn.Module`` models are moved to ``device`` and put in eval mode. With ``check``
    (default) the model is returned as :func:`vp2.models.contract.checked` makes it: every
    ``predict`` call checked, ``name``/``max_batch_size`` defaulted, ``generator``/``grad``
    passed only to a ``predict`` that declares them.

    Raises:
        PluginError: the spec cannot be resolved.
        TypeError: (``check``) the object lacks a required attribute of the interface.
        EnsembleMismatch: (an ensemble) members that differ in their interface sizes.
    """
    import torch

    from vp2.models.contract import checked

    parsed = _parsed(spec)
    if parsed.kind == "ensemble":
        from vp2.models.ensemble import EnsembleModel

        members = [
            resolve_model(m, args, env=env, action_dim=action_dim, device=device)
            for m in parsed.members
        ]
        ensemble = EnsembleModel(members, labels=[m.text for m in parsed.members])
        return checked(ensemble) if check else ensemble
    if parsed.checkpoint is not None:
        parsed.verify()
        # Model arguments of a checkpoint override inference settings of its config
        # (e.g. MCVD's sampling_steps); load_model refuses architecture changes.
        try:
            return parsed.checkpoint.load(device=device, overrides=dict(args or {}))
        except ValueError as err:
            raise PluginError(f"model {parsed.text!r}: {err}") from err
    model = parsed.build(
        args, context={"env": env, "action_dim": action_dim, "device": str(device)}
    )
    if isinstance(model, torch.nn.Module):
        model = model.to(device).eval()
    return checked(model) if check else model


def model_identity(
    spec: str | ModelSpec, args: Mapping[str, Any] | None, model: Any
) -> dict[str, Any]:
    """JSON-able identity of a built model for result records (a zoo model's also names its
    entry: ``zoo``, with the card's family, preset and checkpoint sha256)."""
    import torch

    from vp2.models.contract import unwrap

    name = getattr(model, "name", None)  # a CheckedModel's default: the class name
    model = unwrap(model)
    cls = type(model)
    identity: dict[str, Any] = {
        "spec": str(spec),
        "args": dict(args or {}),
        "name": name if isinstance(name, str) and name else cls.__name__,
        "class": f"{cls.__module__}.{cls.__qualname__}",
    }
    config = getattr(model, "config", None)
    if config is not None and dataclasses.is_dataclass(config):
        identity["config"] = dataclasses.asdict(config)
    if isinstance(model, torch.nn.Module):
        identity["num_parameters"] = sum(p.numel() for p in model.parameters())
    card = _parsed(spec).zoo if str(spec).startswith(ZOO_PREFIX) else None
    if card is not None:
        identity["zoo"] = {"name": card.name, "family": card.family, "preset": card.preset,
                           "sha256": card.sha256}
    members = _parsed(spec).members
    if members:  # an ensemble: each member's identity, in the spec's order
        identity["ensemble"] = [
            model_identity(m, args, built) for m, built in zip(members, model.members, strict=True)
        ]
    return identity


def parse_model_args(items: Sequence[str]) -> dict[str, Any]:
    """``["num_workers=2", "name=foo"]`` -> ``{"num_workers": 2, "name": "foo"}``.

    Values are parsed as YAML scalars/lists (``2`` is an int, ``[1, 2]`` a list,
    ``true`` a bool); anything else stays a string.
    """
    return {k: yaml_value(v) for k, v in parse_key_values(items, "model argument").items()}

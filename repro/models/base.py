"""The one interface every generative method implements: :class:`Generator`.

A method is a subclass naming its :class:`MethodCard` (``card = ...``), from which it takes

- ``method_id``: the short name used in table specs and content keys (``"marionet"``, ...);
- ``Config``: a pydantic model (subclass of :class:`GeneratorConfig`, ``extra="forbid"``) whose
  defaults are the paper's hyper-parameters; scale profiles override fields;
- ``trains_as``, ``inference_fields``, ``components``, ``uses_device``: how a table's jobs are
  made for it (:class:`MethodCard`).

The card and the ``Config`` live in the method's torch-free sibling module ``<module>_config``
(``repro.models.marionet_config`` beside ``repro.models.marionet``), so that a table's plan
reads them (:func:`method_card`) without importing the network, hence torch (issue 31),

and four operations:

- ``Generator(config, skeleton, n_classes, fps)``: ``config`` is a ``Config``, a mapping of
  overrides or ``None`` (the paper defaults); a bad override is a :class:`~repro.errors.ConfigError`;
- ``fit(train_items, *, seed, ckpt_dir=None, on_epoch=None, val_items=None) -> TrainResult``:
  trains through :func:`repro.train.train` (seeded epochs, atomic checkpoints, exact resume;
  use :meth:`Generator.train_config` as the loop's resume guard); with ``val_items`` (held out
  by :func:`repro.train.validation.holdout`) each epoch's history also holds the training loss
  terms measured on them (``val_*``), which never change the weights;
- ``sample(cond_items, *, seed, use_mean=False) -> GeneratedItems``: one generated action per
  condition item, **in the original world frame** (un-normalised), same order;
- ``save(dir)`` / ``Generator.load(dir)``: ``config.json`` (method, config, skeleton, classes,
  fps) beside ``weights.pt`` (a ``state_dict``, read back with ``weights_only=True``).

Conditions differ per method: ACTOR and ODMO read only the label (and the duration); MarioNet,
MANN and the adapted Action2Motion read label + initial motion + duration + next label +
trajectory.  :class:`repro.data.action_items.ActionItems` carries all of them and each method reads
what it uses (declared in ``uses`` so protocols can say what a method saw).
"""

from __future__ import annotations

import abc
import importlib
import json
import os
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar, Mapping

from pydantic import BaseModel, ConfigDict

from repro.config_errors import resolve_config
from repro.errors import ConfigError, DataError, MissingDataError
from repro.keys import canonical_json, content_key
from repro.motion.skeleton import Skeleton
from repro.registries import add_to_registry

CONFIG_FILE = "config.json"
WEIGHTS_FILE = "weights.pt"
SAVE_FORMAT = 1

#: Condition fields a method may read (``Generator.uses``).
CONDITION_FIELDS = frozenset({"label", "length", "initial_motion", "next_label", "trajectory"})


class GeneratorConfig(BaseModel):
    """Base of every method's ``Config``: unknown fields are errors; values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @classmethod
    def resolve(cls, overrides: "GeneratorConfig | Mapping[str, Any] | None" = None,
                *, where: str = "config"):
        """``overrides`` applied over the paper defaults; a ConfigError names the bad field."""
        return resolve_config(cls, overrides, f"{where}: {cls.__qualname__} field")


@dataclass(frozen=True)
class MethodCard:
    """What a table's plan reads of a method, importable without torch: the method's
    ``Config`` and how its jobs are made.  Its Generator subclass takes every field from it
    (``card = ...``, :meth:`Generator.__init_subclass__`)."""

    method_id: str
    Config: type[GeneratorConfig]
    #: the method whose training job this one shares, with the config less ``inference_fields``
    #: (NEURAL MARIONETTE trains as MarioNet); None: its own
    trains_as: str | None = None
    #: Config fields that change only sampling, not what is trained (left out of the training
    #: key and the resume guard)
    inference_fields: Collection[str] = ()
    #: a composite's components, name -> method: it trains nothing of its own; each component
    #: trains as that method does for any other row
    components: Mapping[str, str] = field(default_factory=dict)
    #: whether the method trains and samples with a network on the job's device (a table gives
    #: its train and generate jobs the profile's / ``--device``'s device only then); False for
    #: a method that computes on the CPU whatever the device (``nearest_clip``: retrieval)
    uses_device: bool = True

    @property
    def module(self) -> str:
        """The module that defines (and registers) the method's Generator."""
        return GENERATOR_MODULES[self.method_id]


# ---------------------------------------------------------------------------------------------
# registry: method_id -> class (modules imported lazily so `repro --help` stays fast)

#: method_id -> module that defines (and registers) it, beside its torch-free ``<module>_config``
#: (its Config and :class:`MethodCard`).  Add a line per new method.
GENERATOR_MODULES: dict[str, str] = {
    "marionet": "repro.models.marionet",
    "neural_marionette": "repro.models.neural_marionette",
    "nearest_clip": "repro.models.nearest_clip",
    "mann": "repro.models.mann",
    "a2m": "repro.models.a2m",
    "actor": "repro.models.actor",
    "macvae": "repro.models.macvae",
    "ssmct": "repro.models.ssmct",
    "actor_ssmct": "repro.models.multiact_baselines",
    "interpolation": "repro.models.multiact_baselines",
    "act_mocogan": "repro.models.act_mocogan",
    "dlow_gen": "repro.models.dlow_gen",
    "odmo": "repro.models.odmo",
}
_REGISTRY: dict[str, type["Generator"]] = {}
_CARDS: dict[str, MethodCard] = {}


def register(cls: type["Generator"]) -> type["Generator"]:
    """Class decorator: make ``cls`` findable by :func:`generator_class`."""
    return add_to_registry(_REGISTRY, cls, "method_id", "method_id")


def register_card(card: MethodCard) -> MethodCard:
    """Make ``card`` findable by :func:`method_card` (in the method's ``<module>_config``)."""
    return add_to_registry(_CARDS, card, "method_id", "method card")


def generator_class(method_id: str) -> type["Generator"]:
    """The Generator subclass registered under ``method_id`` (ConfigError if unknown)."""
    if method_id not in _REGISTRY and method_id in GENERATOR_MODULES:
        importlib.import_module(GENERATOR_MODULES[method_id])
    return _registered(_REGISTRY, method_id)


def method_card(method_id: str) -> MethodCard:
    """The :class:`MethodCard` of ``method_id`` (ConfigError if unknown), from the method's
    ``<module>_config`` alone: the network module (and torch) is not imported."""
    if method_id not in _CARDS and method_id in GENERATOR_MODULES:
        name = f"{GENERATOR_MODULES[method_id]}_config"
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name != name:
                raise
            raise ConfigError(f"method {method_id!r}: its card module {name} is missing (each "
                              f"method's Config and MethodCard live there, torch-free)") from None
    return _registered(_CARDS, method_id)


def _registered(registry: dict, method_id: str):
    """``registry[method_id]``, else a ConfigError naming the nearest known method."""
    try:
        return registry[method_id]
    except KeyError:
        import difflib

        known = sorted(set(GENERATOR_MODULES) | set(registry))
        near = difflib.get_close_matches(method_id, known, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else f"; known: {', '.join(known)}"
        raise ConfigError(f"unknown method {method_id!r}{hint}") from None


# ---------------------------------------------------------------------------------------------


class Generator(abc.ABC):
    """A trainable action-conditioned motion generator (see module docstring)."""

    #: the method's card: ``method_id``, ``Config`` and the fields below are its
    card: ClassVar[MethodCard]
    method_id: ClassVar[str]
    Config: ClassVar[type[GeneratorConfig]]
    trains_as: ClassVar[str | None] = None
    inference_fields: ClassVar[Collection[str]] = ()
    components: ClassVar[Mapping[str, str]] = {}
    uses_device: ClassVar[bool] = True
    #: the condition fields (``CONDITION_FIELDS``) this method reads
    uses: ClassVar[frozenset[str]] = frozenset({"label", "length"})

    def __init_subclass__(cls, **kwargs):
        """A subclass naming its ``card`` takes its method id, Config and job facts from it."""
        super().__init_subclass__(**kwargs)
        card = cls.__dict__.get("card")
        if card is not None:
            cls.method_id, cls.Config, cls.trains_as = card.method_id, card.Config, card.trains_as
            cls.inference_fields, cls.components = card.inference_fields, card.components
            cls.uses_device = card.uses_device

    def __init__(self, config: GeneratorConfig | Mapping[str, Any] | None, skeleton: Skeleton,
                 n_classes: int, fps: float):
        self.config = self.Config.resolve(config, where=self.method_id)
        if not isinstance(skeleton, Skeleton):
            raise TypeError("skeleton must be a repro.motion.skeleton.Skeleton")
        if int(n_classes) < 1:
            raise ConfigError(f"{self.method_id}: n_classes must be >= 1, got {n_classes}")
        if not float(fps) > 0:
            raise ConfigError(f"{self.method_id}: fps must be > 0, got {fps}")
        self.skeleton = skeleton
        self.n_classes = int(n_classes)
        self.fps = float(fps)

    # -- what the subclass provides ----------------------------------------------------------

    @property
    @abc.abstractmethod
    def network(self):
        """The ``torch.nn.Module`` holding every learned parameter and buffer."""

    @abc.abstractmethod
    def fit(self, train_items, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items=None):
        """Train on ``train_items`` (an ActionItems); returns :class:`repro.train.loop.TrainResult`.
        ``val_items`` (an ActionItems or None): held-out items whose loss terms, computed as in
        training, enter each epoch's history as ``val_*`` (a curve only: nothing is selected
        with it, and the weights are the same with or without it)."""

    @abc.abstractmethod
    def sample(self, cond_items, *, seed: int, use_mean: bool = False):
        """One action per item of ``cond_items``: a GeneratedItems in the world frame."""

    # -- shared --------------------------------------------------------------------------------

    @property
    def device(self):
        """The ``torch.device`` the network lives on: sampling makes its tensors there and
        returns its results on the CPU (``fit`` trains on the job's device,
        :func:`repro.train.loop.use_device`)."""
        from repro.train.loop import module_device

        return module_device(self.network)

    def to(self, device) -> "Generator":
        """Move the network to ``device`` (a name or ``torch.device``) for sampling; returns
        ``self``.  Saved weights load on the CPU wherever they were trained."""
        self.network.to(device)
        return self

    def _make_network(self):
        """A fresh, untrained ``torch.nn.Module`` for this config (subclasses using :meth:`_build`)."""
        raise NotImplementedError

    def _build(self, init_seed: int) -> None:
        """(Re)build ``self.net`` with initial weights drawn from ``init_seed`` alone (the global
        torch RNG is left as it was), in eval mode."""
        import torch

        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(init_seed)
            self.net = self._make_network()
        self.net.eval()

    def _fit_items(self, train_items, check, make_optimizer, *, seed: int, ckpt_dir, on_epoch,
                   val_items=None):
        """The whole ``fit`` of a method with no extra step: ``check(self, items)`` on the
        training (and validation) items, fresh weights from ``seed``, ``self._tensors`` of the
        items, ``make_optimizer(parameters)``, then :meth:`_fit_batches`."""
        from repro.seeding import derive_seed

        check(self, train_items)
        if val_items is not None:
            check(self, val_items)
        self._build(derive_seed(seed, self.method_id, "init"))
        data = self._tensors(train_items)
        opt = make_optimizer(self.net.parameters())
        val_data = None if val_items is None else self._tensors(val_items)
        return self._fit_batches(train_items, data, opt, seed=seed, ckpt_dir=ckpt_dir,
                                 on_epoch=on_epoch, val_items=val_items, val_data=val_data)

    def _fit_adamw(self, train_items, check, *, seed: int, ckpt_dir, on_epoch, val_items=None):
        """:meth:`_fit_items` with AdamW at the config's ``lr`` and ``weight_decay``
        (:func:`repro.kernels.adamw`)."""
        from repro import kernels

        cfg = self.config
        return self._fit_items(
            train_items, check,
            lambda params: kernels.adamw(params, lr=cfg.lr, weight_decay=cfg.weight_decay),
            seed=seed, ckpt_dir=ckpt_dir, on_epoch=on_epoch, val_items=val_items)

    def _fit_batches(self, train_items, data: dict, optimizer, *, seed: int, ckpt_dir,
                     on_epoch, val_items=None, val_data: dict | None = None, **train_kwargs):
        """The tail every item-batched ``fit`` shares: shuffled batches of ``config.batch_size``
        items (``self._crop(data, idx)`` each), ``self.training_step`` through the one
        training loop (:func:`repro.train.loop.train`, resumable from ``ckpt_dir``), then
        eval mode.  ``train_kwargs`` go to the loop (e.g. ``grad_clip``).  With ``val_items``
        and their tensors ``val_data`` (made like ``data``), each epoch's record also holds
        ``self.training_step`` on them (:meth:`_validator`)."""
        from repro.train.loop import train

        n, batch_size = len(train_items), self.config.batch_size

        def batches(epoch, gen):
            for idx in epoch_batches(n, batch_size, gen):
                yield self._crop(data, idx)

        validate = None
        if val_items is not None:
            if val_data is None:
                raise ValueError("val_items need their tensors (val_data)")
            validate = self._validator(val_data, len(val_items), batch_size)
        result = train(self.net, optimizer, batches=batches, step=self.training_step,
                       epochs=self.config.epochs, seed=seed,
                       config=self.train_config(train_items, seed, val_items),
                       ckpt_dir=ckpt_dir, on_epoch=on_epoch, validate=validate, **train_kwargs)
        self.net.eval()
        return result

    def _validator(self, val_data: dict, n_val: int, batch_size: int):
        """The training loop's ``validate``: ``self.training_step`` on the validation items in
        order, in batches of ``batch_size``, each scalar averaged over items (so ``val_loss``
        is the training loss on held-out items; the loop runs it in eval mode, no dropout)."""
        import torch

        from repro.train.loop import module_device, to_device

        def validate(model, epoch):
            sums: dict[str, float] = {}
            dev = module_device(model)
            for s in range(0, n_val, batch_size):
                idx = torch.arange(s, min(n_val, s + batch_size))
                out = self.training_step(model, to_device(self._crop(val_data, idx), dev), epoch)
                w = idx.numel()
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + w * float(v.detach() if hasattr(v, "detach") else v)
            return {k: v / max(n_val, 1) for k, v in sums.items()}

        return validate

    def plateau_rule(self):
        """The convergence rule of this method's trainings (:mod:`repro.train.plateau`, issue 32):
        by default the held-out ``val_loss``; a method whose loss changes meaning during
        training overrides it with a quantity that keeps its meaning, or with the first epoch
        from which the loss is comparable."""
        from repro.train.plateau import PlateauRule

        return PlateauRule()

    def describe(self) -> dict:
        """Everything that defines this generator before training (enters content keys)."""
        return {"method_id": self.method_id, "config": self.config.model_dump(mode="json"),
                "skeleton": self.skeleton.fingerprint(), "n_classes": self.n_classes,
                "fps": self.fps}

    def train_config(self, train_items, seed: int, val_items=None) -> dict:
        """The resume guard for :func:`repro.train.train`: a checkpoint is resumed only when
        the generator, the training items and the seed are all the same (and the validation
        items, when there are any: the history in the checkpoint holds their curve)."""
        cfg = {"generator": self.describe(), "items": train_items.key(), "seed": int(seed)}
        if val_items is not None:
            cfg["validation"] = val_items.key()
        return cfg

    def key(self) -> str:
        return content_key(self.describe())

    def save(self, directory: str | Path) -> Path:
        """Write ``config.json`` and ``weights.pt`` into ``directory`` (atomically each)."""
        import torch

        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        meta = {"format": SAVE_FORMAT, "method_id": self.method_id,
                "config": self.config.model_dump(mode="json"), "skeleton": self.skeleton.to_dict(),
                "n_classes": self.n_classes, "fps": self.fps}
        tmp = d / f".{WEIGHTS_FILE}.{os.getpid()}.tmp"
        state = self.network.state_dict()
        if self.device.type != "cpu":  # saved as CPU tensors: a CUDA-trained model loads anywhere
            from repro.train.loop import to_device

            state = to_device(state, "cpu")
        # through a file handle: given a path, torch names the zip's inner folder after it, so
        # the pid-named temp path made the bytes differ between processes
        with open(tmp, "wb") as fh:
            torch.save(state, fh)
        os.replace(tmp, d / WEIGHTS_FILE)
        tmp = d / f".{CONFIG_FILE}.{os.getpid()}.tmp"
        tmp.write_bytes(canonical_json(meta))
        os.replace(tmp, d / CONFIG_FILE)
        return d

    @classmethod
    def load(cls, directory: str | Path) -> "Generator":
        """Rebuild a saved generator; on the base class the saved ``method_id`` picks the class."""
        import torch

        d = Path(directory)
        cfg_path, w_path = d / CONFIG_FILE, d / WEIGHTS_FILE
        for p in (cfg_path, w_path):
            if not p.is_file():
                raise MissingDataError(f"no saved generator here (missing {p.name})", d)
        try:
            meta = json.loads(cfg_path.read_text())
            method_id = meta["method_id"]
            skeleton = Skeleton.from_dict(meta["skeleton"])
        except (ValueError, KeyError, TypeError) as e:
            raise DataError(f"unreadable generator config ({e})", cfg_path) from None
        if meta.get("format") != SAVE_FORMAT:
            raise DataError(f"unsupported save format {meta.get('format')!r}", cfg_path)
        klass = generator_class(method_id) if cls is Generator else cls
        if klass.method_id != method_id:
            raise DataError(f"saved method is {method_id!r}, not {klass.method_id!r}", cfg_path)
        gen = klass(meta["config"], skeleton, meta["n_classes"], meta["fps"])
        try:
            state = torch.load(w_path, map_location="cpu", weights_only=True)
            gen.network.load_state_dict(state)
        except Exception as e:  # torn file, foreign weights, shape mismatch
            raise DataError(f"cannot load weights ({type(e).__name__}: {e})", w_path) from None
        gen.network.eval()
        return gen


def epoch_batches(n_items: int, batch_size: int, generator, *, drop_last: bool = False):
    """Index batches of one epoch: a permutation drawn only from ``generator`` (the training
    loop's per-epoch ``torch.Generator``), cut into ``batch_size`` chunks."""
    import torch

    perm = torch.randperm(n_items, generator=generator)
    stop = n_items - n_items % batch_size if drop_last else n_items
    return [perm[i:i + batch_size] for i in range(0, stop, batch_size) if len(perm[i:i + batch_size])]

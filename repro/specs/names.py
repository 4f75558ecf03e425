"""Fixed vocabularies of the table specs: papers, data sets, methods, metrics, protocols,
interval conventions.

Other modules import these names; a spec that uses a name not listed here is refused with a
did-you-mean suggestion (:func:`check_name`).  Extend a vocabulary when a table needs more,
always with a one-line description.

Sources: the three paper texts in ``../shared/papers/`` and ``../shared/docs/protocols.md``
(§1.6 for the interval conventions).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from repro.errors import SpecError


@dataclass(frozen=True)
class PaperInfo:
    key: str
    title: str
    file: str  # the text extraction in ../shared/papers/
    short: str


@dataclass(frozen=True)
class DatasetInfo:
    id: str
    display: str
    standin: bool  # True: runnable stand-in shipped or prepared by repro; False: a paper's data set
    description: str


@dataclass(frozen=True)
class MethodInfo:
    id: str
    display: str
    defined_by: str  # paper key, "harness", or "external: <citation>" for a cited method
    description: str


@dataclass(frozen=True)
class MetricInfo:
    id: str
    display: str
    unit: str  # "" when dimensionless
    direction: str  # default direction: lower | higher | closer_to_real
    description: str


def _freeze(items) -> Mapping:
    return MappingProxyType({i.id if hasattr(i, "id") else i.key: i for i in items})


PAPERS: Mapping[str, PaperInfo] = MappingProxyType({
    "marionette": PaperInfo(
        "marionette",
        "Neural Marionette: A Transformer-based Multi-action Human Motion Synthesis System",
        "000_284491a9604abf8e.txt", "Neural Marionette"),
    "multiact": PaperInfo(
        "multiact",
        "MultiAct: Long-Term 3D Human Motion Generation from Multiple Action Labels",
        "001_16d3e0a1644ea1c8.txt", "MultiAct"),
    "odmo": PaperInfo(
        "odmo", "Action-conditioned On-demand Motion Generation",
        "002_4147e0231268d194.txt", "ODMO"),
})

#: Interval conventions for the paper-style "±" (protocols.md §1.6).  repro.stats.intervals
#: implements one function per name; R is the number of replicates, sd the sample std (ddof 1).
INTERVALS: Mapping[str, str] = MappingProxyType({
    "z_sem": "1.96·sd/√R (normal approximation of the mean's 95% interval)",
    "t_sem": "t(0.975, R−1)·sd/√R (Student-t; MultiAct's tester, R = 20)",
    "z_sd_sqrt_nm1": "1.96·sd/√(R−1) (ODMO's confidence_interval, R = 10)",
    "z_var": "1.96·variance (population variance; ACTOR's easy_table quirk, R = 20)",
    "none": "no ± printed (Neural Marionette)",
})

#: The only values a column's or claim's direction may take.
DIRECTIONS = ("lower", "higher", "closer_to_real")
#: The shapes a trend claim may assert.
TREND_DIRECTIONS = ("decreasing", "increasing", "stable")

DATASETS: Mapping[str, DatasetInfo] = _freeze([
    DatasetInfo("bandai2", "Bandai-Namco-2 (stand-in)", True,
                "Bandai-Namco-Research-Motiondataset-2: 2,902 real mocap clips, 10 actions × 7 "
                "styles, 30 fps; the default stand-in for every paper data set"),
    DatasetInfo("bandai2-mini", "Bandai-Namco-2 mini (bundled stand-in)", True,
                "small deterministic subset of bandai2 bundled with the package (quick scale)"),
    DatasetInfo("babel-mag", "BABEL-MAG", False,
                "Neural Marionette's relabelled BABEL subset: 31 tags, 7,643 actions, 30 Hz"),
    DatasetInfo("babel", "BABEL", False,
                "BABEL v1.0 over AMASS; MultiAct uses 53 labels at 20 fps, train/val splits"),
    DatasetInfo("humanact12", "HumanAct12", False,
                "1,191 clips, 12 actions, 24 SMPL joints (Action2Motion's release)"),
    DatasetInfo("uestc", "UESTC", False,
                "40 actions, 18-joint xyz as preprocessed by ACTOR; train/test split"),
    DatasetInfo("cmu-mocap", "CMU MoCap", False,
                "Action2Motion's CMU MoCap subset, 7 actions after ODMO drops 'Wash', 20 joints"),
])

METHODS: Mapping[str, MethodInfo] = _freeze([
    MethodInfo("real", "Real data", "harness",
               "the real-data row: real clips scored like generated ones (split via overrides)"),
    MethodInfo("nearest_clip", "Nearest real clip", "harness",
               "reference retrieval method of the harness (returns the closest training clip); "
               "never a paper method"),
    MethodInfo("marionet", "MarioNet", "marionette",
               "Neural Marionette's transformer CVAE (condition encoder, time unrolling, tag "
               "injection, AR motion decoder); in multi-action tables the pure generative pipeline"),
    MethodInfo("neural_marionette", "Neural Marionette", "marionette",
               "MarioNet chained by Alg. 1 with the Shadow Start / Action Revision switches"),
    MethodInfo("mann", "MANN", "external: Zhang et al. 2018; adapted by marionette",
               "Mode-Adaptive Neural Networks (Zhang et al. 2018) adapted by Neural Marionette "
               "(supp. §4.1)"),
    MethodInfo("a2m", "Action2Motion", "external: Guo et al. 2020 (Action2Motion)",
               "Action2Motion GRU-VAE (Guo et al. 2020); variants via overrides (representation, "
               "initial pose as in Neural Marionette supp. §4.1)"),
    MethodInfo("actor", "ACTOR", "external: Petrovich et al. 2021 (ACTOR)",
               "ACTOR transformer VAE (Petrovich et al. 2021), label-conditioned only"),
    MethodInfo("macvae", "MACVAE", "multiact",
               "MultiAct's single-step CVAE (PrevNet, CurrNet, transformer encoder/decoder)"),
    MethodInfo("multiact", "MultiAct", "multiact",
               "MultiAct's recurrent long-term generation with MACVAE and face-front canon."),
    MethodInfo("actor_ssmct", "ACTOR + SSMCT", "multiact",
               "MultiAct's combined baseline: ACTOR actions joined by SSMCT in-betweening "
               "(Duan et al. 2021)"),
    MethodInfo("interpolation", "ACTOR + Interpolation", "multiact",
               "MultiAct's baseline: ACTOR actions joined by linear interpolation"),
    MethodInfo("ssmct", "SSMCT", "external: Duan et al. 2021 (SSMCT)",
               "transformer in-betweening model, the transition part of ACTOR + SSMCT "
               "(trained on the stand-in's pairs)"),
    MethodInfo("odmo", "ODMO", "odmo",
               "ODMO contrastive VAE with trajectory and motion generators; sampling and "
               "ablations via overrides"),
    MethodInfo("dlow_gen", "DLow-Gen", "odmo",
               "DLow (Yuan & Kitani 2020) with the motion history replaced by the class label "
               "(ODMO §4.2.3)"),
    MethodInfo("act_mocogan", "Act-MoCoGAN", "odmo",
               "MoCoGAN with a pose generator, as modified by Action2Motion (ODMO §4.2.3)"),
])

METRICS: Mapping[str, MetricInfo] = _freeze([
    MetricInfo("fid", "FID", "", "lower", "Fréchet distance of classifier features, generated vs real"),
    MetricInfo("fid_train", "FID_train", "", "lower", "FID against the training-split reference"),
    MetricInfo("fid_test", "FID_test", "", "lower", "FID against the test-split reference"),
    MetricInfo("acc", "Acc", "fraction", "higher", "top-1 recognition accuracy of the evaluator"),
    MetricInfo("acc_top5", "Acc top-5", "fraction", "higher", "top-5 recognition accuracy"),
    MetricInfo("div", "Div", "", "closer_to_real",
               "diversity: mean feature distance of random pairs across classes (A2M, 200 pairs)"),
    MetricInfo("multimod", "Multimod", "", "closer_to_real",
               "multimodality: mean feature distance of same-class pairs (A2M, 20 per class)"),
    MetricInfo("n_apd", "n-APD", "%", "closer_to_real",
               "ODMO's normalised average pairwise distance, generated / real APD per class × 100"),
    MetricInfo("traj_err", "Δ_Traj", "", "lower",
               "per-frame L2 between the input trajectory and the generated root (units unstated)"),
    MetricInfo("jpe", "Δ_JPE", "", "lower",
               "joint position error (Neural Marionette Table 2; undefined in the text)"),
    MetricInfo("pose_gap", "Δ_pose", "cm", "lower",
               "L2 of per-joint positions between an action's last and the next one's first frame"),
    MetricInfo("vel_gap", "Δ_vel", "cm/frame", "lower",
               "difference of per-joint velocity across the boundary between two actions"),
    MetricInfo("action_qr", "Action QR", "fraction", "higher",
               "mean over sequences of the fraction of correctly recognised actions"),
    MetricInfo("motion_qr", "Motion QR", "fraction", "higher",
               "fraction of sequences whose actions are all recognised correctly"),
    MetricInfo("mode_homogeneity", "mode-homogeneity", "%", "higher",
               "ODMO §4.3.1: relative APD decrease when real sequences are split by latent modes"),
    MetricInfo("dist_e", "dist_e", "", "lower",
               "ODMO §4.4: squared distance between target and generated end location"),
    # harness columns, in none of the papers (repro.eval.protocols.latent_modes)
    MetricInfo("style_ami", "Style AMI", "", "higher",
               "harness: adjusted mutual information (chance-corrected) between latent modes and "
               "the stand-in's recorded styles, per class then averaged"),
    MetricInfo("style_nmi", "Style NMI", "", "higher",
               "harness: normalised mutual information between latent modes and the stand-in's "
               "recorded styles, per class then averaged"),
    MetricInfo("style_ari", "Style ARI", "", "higher",
               "harness: adjusted Rand index between latent modes and the recorded styles, per "
               "class then averaged"),
    MetricInfo("style_coverage", "Style coverage", "%", "higher",
               "harness: share of a class's styles among mode-preserving sampled codes (each "
               "takes its nearest encoded window's style), averaged over classes"),
    # harness columns, in none of the papers (repro.eval.memorisation)
    MetricInfo("nn_train_feat", "NN-train (features)", "", "closer_to_real",
               "harness: mean evaluator-feature distance of a sample to its nearest training "
               "action (a copier scores ~0)"),
    MetricInfo("nn_train_joint", "NN-train (joints)", "m", "closer_to_real",
               "harness: mean RMS per-joint distance (normalised frame) of a sample to its "
               "nearest training action (a copier scores 0)"),
    MetricInfo("precision", "Precision", "fraction", "higher",
               "harness: share of samples inside the real features' k-NN balls "
               "(Kynkäänniemi et al. 2019)"),
    MetricInfo("recall", "Recall", "fraction", "higher",
               "harness: share of real features inside the samples' k-NN balls "
               "(Kynkäänniemi et al. 2019)"),
    MetricInfo("density", "Density", "", "higher",
               "harness: mean count of real k-NN balls holding a sample, over k (Naeem et al. 2020)"),
    MetricInfo("coverage", "Coverage", "fraction", "higher",
               "harness: share of real features whose ball holds a sample (Naeem et al. 2020)"),
])

PROTOCOLS: Mapping[str, str] = MappingProxyType({
    "single_action": "one action per sample from tag + context (initial motion, next tag, "
                     "duration, trajectory); Neural Marionette Tables 1, 2 and 4 (single)",
    "multi_action": "20-action sequences chained by the pure generative pipeline on the overall "
                    "and sufficient sets, scored from action 2 on; Marionette Tables 3, 4, Fig. 8",
    "ss_ar": "multi-action generation with Shadow Start / Action Revision variants on the "
             "overall set; Marionette Table 5 and Fig. 10",
    "multiact_conditioned": "one MACVAE step from an unseen previous motion and a label, scored "
                            "on the generated action (20 per label); MultiAct Tables 1, 2, A, B",
    "transition": "FID of generated transitions against real transitions (train and test); "
                  "MultiAct Table 3",
    "long_term": "recurrent long-term generation scored per step (action Acc, transition FID); "
                 "MultiAct Fig. 6",
    "odmo_generation": "label-conditioned generation, per-class sample sets scored by the "
                       "evaluator (Acc, FID, Div, MModality) and n-APD; ODMO Tables 1, 2, S1",
    "latent_modes": "GMM/silhouette modes in a method's latent space scored by "
                    "mode-homogeneity on real sequences; ODMO Table 3",
    "trajectory_customisation": "generation to requested end locations (code + end point), "
                                "scored by Acc and dist_e; ODMO Table 4",
})


def _vocab(kind: str) -> Mapping:
    return {
        "paper": PAPERS, "dataset": DATASETS, "method": METHODS, "metric": METRICS,
        "protocol": PROTOCOLS, "interval": INTERVALS,
    }[kind]


def suggest(name: str, choices) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or ``''`` when none is close."""
    close = difflib.get_close_matches(str(name), list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def unknown_name_message(kind: str, name: str, choices=None) -> str:
    """``unknown method 'marionett' (did you mean 'marionet'?)``."""
    choices = list(_vocab(kind)) if choices is None else list(choices)
    return f"unknown {kind} {name!r}{suggest(name, choices)}"


def require_known(kind: str, name: str) -> str:
    """``name`` if it is in the ``kind`` vocabulary, else ``ValueError`` with the did-you-mean
    message (the form pydantic validators raise; :func:`check_name` raises a SpecError)."""
    if name not in _vocab(kind):
        raise ValueError(unknown_name_message(kind, name))
    return name


def require_standin(name: str) -> str:
    """``name`` if it is a known stand-in data set, else ``ValueError``."""
    require_known("dataset", name)
    if not DATASETS[name].standin:
        raise ValueError(f"{name!r} is a paper data set, not a stand-in "
                         f"(choose from {', '.join(standin_datasets())})")
    return name


def check_name(kind: str, name: str, *, file=None, location: str | None = None,
               standin_only: bool = False) -> str:
    """Return ``name`` if it is in the ``kind`` vocabulary (and a stand-in data set, with
    ``standin_only``), else raise a :class:`SpecError` with a did-you-mean suggestion naming
    ``file`` and ``location``."""
    try:
        require_known(kind, name)
        return require_standin(name) if standin_only else name
    except ValueError as e:
        raise SpecError(str(e), file, location) from None


def standin_datasets() -> tuple[str, ...]:
    return tuple(d for d, info in DATASETS.items() if info.standin)


STANDIN, PAPER, OWN = "stand-in", "paper", "own"


def dataset_kind(name: str) -> str:
    """What a data set is: :data:`STANDIN` (a built-in stand-in the harness ships or
    prepares), :data:`PAPER` (a paper's, in :data:`DATASETS`) or :data:`OWN` (any other name:
    one a data-set spec declares, never called a stand-in; issue 28)."""
    info = DATASETS.get(name)
    return OWN if info is None else STANDIN if info.standin else PAPER

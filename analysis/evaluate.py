"""Score label-id predictions against a Cityscapes export with cityscapesScripts.

cityscapesScripts 2.3's ``csEvalPixelLevelSemanticLabeling`` command stops on
numpy >= 2.4 in its instance-level part (``np.in1d`` was removed), and only
looks in ``gtFine/val`` of ``$CITYSCAPES_DATASET``. ``evaluate`` calls the
same module's API instead: its own file matching (``getPrediction``: a
prediction for ``<city>_<seq>_<frame>_gtFine_labelIds.png`` is any
``<city>_<seq>_<frame>*.png`` under the predictions directory) and its
``evaluateImgLists``, with the instance-level score and the pixel accuracy
(the two parts that call ``np.in1d``) turned off. The class and category IoUs
are cityscapesScripts' own numbers.

``evaluate_instances`` runs its instance-level evaluation
(``evalInstanceLevelSemanticLabeling``) on the export's instanceIds images;
that module gets a numpy namespace with ``in1d`` bound to ``isin``
(``numpy_with_in1d``), scoped to that module only, and its steps run without
its JSON dumps, which fail on numpy 2's integer scalars.
"""

from __future__ import annotations

import contextlib
import copy
import glob
import io
import math
import os
from dataclasses import dataclass

from manifests.query import SPLITS


@dataclass(frozen=True)
class EvaluateConfig:
    export: str  # a Cityscapes export (idda export --format cityscapes)
    predictions: str  # directory searched for <city>_<seq>_<frame>*.png label-id images
    split: str = "val"  # ground truth: gtFine/<split>/*/*_gtFine_labelIds.png
    json_out: str | None = None  # also write cityscapesScripts' result JSON here

    def validate(self) -> None:
        if self.split not in SPLITS:
            raise ValueError(f"unknown split {self.split!r}; valid splits: {', '.join(SPLITS)}")
        if not os.path.isdir(self.predictions):
            raise ValueError(f"predictions directory {self.predictions} does not exist")


@dataclass
class EvaluateReport:
    images: int
    miou: float  # mean class IoU over the classes present (cityscapesScripts' "Score Average")
    miou_categories: float
    class_iou: dict[str, float]  # NaN for classes absent from ground truth and prediction
    category_iou: dict[str, float]


def _module():
    try:
        from cityscapesscripts.evaluation import evalPixelLevelSemanticLabeling as module
    except ImportError as exc:
        raise ImportError("idda evaluate needs cityscapesScripts: pip install cityscapesscripts") from exc
    return module


@contextlib.contextmanager
def _quiet(what: str):
    """cityscapesScripts prints and calls sys.exit on errors: turn that into a ValueError."""
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            yield
    except SystemExit:
        message = " ".join(out.getvalue().split()) or "cityscapesScripts stopped"
        raise ValueError(f"{what}: {message}") from None


def evaluate(config: EvaluateConfig) -> EvaluateReport:
    """Pixel-level IoU of the predictions against the export's ``split``."""
    config.validate()
    module = _module()
    truth = sorted(glob.glob(os.path.join(config.export, "gtFine", config.split, "*", "*_gtFine_labelIds.png")))
    if not truth:
        raise ValueError(f"{config.export} has no gtFine/{config.split}/*/*_gtFine_labelIds.png (not a Cityscapes export?)")
    args = copy.deepcopy(module.args)
    args.evalInstLevelScore = False  # calls np.in1d, gone in numpy 2.4
    args.evalPixelAccuracy = False  # same
    args.quiet = True
    args.colorized = False
    args.bold = args.nocol = ""
    args.predictionPath = os.path.abspath(config.predictions)
    args.predictionWalk = None
    args.JSONOutput = config.json_out is not None
    if config.json_out is not None:
        args.exportFile = config.json_out
    with _quiet("matching predictions"):
        predicted = [module.getPrediction(args, gt) for gt in truth]
    with _quiet("evaluating"):
        result = module.evaluateImgLists(predicted, truth, args)
    classes = {name: float(score) for name, score in result["classScores"].items()}
    categories = {name: float(score) for name, score in result["categoryScores"].items()}
    return EvaluateReport(
        images=len(truth),
        miou=float(result["averageScoreClasses"]),
        miou_categories=float(result["averageScoreCategories"]),
        class_iou=classes,
        category_iou=categories,
    )


def format_report(report: EvaluateReport) -> str:
    lines = [f"{'class':<16} {'IoU':>6}"]
    for name, score in report.class_iou.items():
        if not math.isnan(score):
            lines.append(f"{name:<16} {score:>6.3f}")
    lines.append(f"mIoU {report.miou:.3f} over classes, {report.miou_categories:.3f} over categories "
                 f"({report.images:,} images)")
    return "\n".join(lines)


def numpy_with_in1d():
    """numpy as cityscapesScripts 2.3 calls it: a module namespace with ``in1d``
    (removed in numpy 2.4) bound to ``isin``. Given to one cityscapesScripts
    module as its ``np``; numpy itself is not changed."""
    import types

    import numpy

    shim = types.ModuleType("numpy")
    shim.__dict__.update(numpy.__dict__)
    shim.in1d = numpy.isin
    return shim


def instance_eval_module():
    """cityscapesScripts' evalInstanceLevelSemanticLabeling, its ``np`` given ``in1d`` where numpy lacks it."""
    try:
        from cityscapesscripts.evaluation import evalInstanceLevelSemanticLabeling as module
    except ImportError as exc:
        raise ImportError("instance evaluation needs cityscapesScripts: pip install cityscapesscripts") from exc
    if not hasattr(module.np, "in1d"):
        module.np = numpy_with_in1d()
    return module


def evaluate_instances(export: str, predictions: str, split: str = "val", min_region_px: int = 100) -> dict:
    """cityscapesScripts' instance-level AP of ``predictions`` (its txt + mask
    format) against the export's ``*_gtFine_instanceIds.png``; returns its
    averages (``allAp``, ``allAp50%``, per class ``ap``). ``min_region_px``
    replaces its smallest ground-truth region size (100 px) for small frames."""
    import numpy as np

    module = instance_eval_module()
    truth = sorted(glob.glob(os.path.join(export, "gtFine", split, "*", "*_gtFine_instanceIds.png")))
    if not truth:
        raise ValueError(f"{export} has no gtFine/{split}/*/*_gtFine_instanceIds.png (not a Cityscapes export?)")
    args = copy.deepcopy(module.args)
    args.quiet = True
    args.colorized = False
    args.JSONOutput = False
    args.minRegionSizes = np.array([min_region_px, max(min_region_px, 1000), max(min_region_px, 1000)])
    args.predictionPath = os.path.abspath(predictions)
    args.predictionWalk = None
    with _quiet("matching predictions"):
        predicted = [module.getPrediction(gt, args) for gt in truth]
    # evaluateImgLists' steps, without its JSON dumps (they fail on numpy 2 integers)
    with _quiet("evaluating instances"):
        module.setInstanceLabels(args)
        gt_instances = module.instances2dict(truth, False)
        matches = module.matchGtWithPreds(predicted, truth, gt_instances, args)
        return module.computeAverages(module.evaluateMatches(matches, args), args)

"""Segmentation scores over the catalog's evaluated classes (plain numpy, no torch).

Scores are accumulated in a confusion matrix over the evaluated classes
(``EVAL_CLASSES``, the 16 classes the paper scores); pixels of the other
classes are ignored. The mean IoU averages over the classes present in the
ground truth of the scored set, so a class the set never shows neither helps
nor hurts; predicting it where another class is still costs that class.
"""

from __future__ import annotations

import numpy as np

from domains.catalog import EVALUATED_IDS, LABELS

IGNORE = 255  # training index of pixels that are not scored
EVAL_CLASSES: tuple[str, ...] = tuple(LABELS[i].name for i in EVALUATED_IDS)
NUM_EVAL = len(EVAL_CLASSES)

# IDDA class id -> training index 0..NUM_EVAL-1 (IGNORE for classes not evaluated).
TRAIN_INDEX_LUT = np.full(256, IGNORE, dtype=np.uint8)
TRAIN_INDEX_LUT[np.asarray(EVALUATED_IDS)] = np.arange(NUM_EVAL, dtype=np.uint8)


def confusion(gt: np.ndarray, pred: np.ndarray, num_classes: int = NUM_EVAL) -> np.ndarray:
    """``num_classes`` x ``num_classes`` pixel counts, rows ground truth, columns prediction.

    Both arrays hold training indices; pixels whose ground truth is outside
    ``[0, num_classes)`` (``IGNORE``) are skipped. Predictions must be valid indices.
    """
    gt = np.asarray(gt).ravel().astype(np.int64)
    pred = np.asarray(pred).ravel().astype(np.int64)
    if gt.shape != pred.shape:
        raise ValueError(f"ground truth and prediction differ in size: {gt.size} vs {pred.size} pixels")
    keep = (gt >= 0) & (gt < num_classes)
    if np.any((pred[keep] < 0) | (pred[keep] >= num_classes)):
        raise ValueError(f"predictions must be class indices in [0, {num_classes})")
    flat = gt[keep] * num_classes + pred[keep]
    return np.bincount(flat, minlength=num_classes * num_classes).reshape(num_classes, num_classes)


def class_iou(matrix: np.ndarray) -> np.ndarray:
    """IoU per class from a confusion matrix; NaN for classes absent from the ground truth."""
    matrix = np.asarray(matrix, dtype=np.float64)
    tp = np.diag(matrix)
    gt = matrix.sum(axis=1)
    union = gt + matrix.sum(axis=0) - tp
    iou = np.full(len(tp), np.nan)
    present = gt > 0
    iou[present] = tp[present] / union[present]
    return iou


def mean_iou(matrix: np.ndarray) -> float:
    """Mean IoU over the classes present in the ground truth (0 ≤ value ≤ 1)."""
    iou = class_iou(matrix)
    if np.all(np.isnan(iou)):
        raise ValueError("no scored pixels: the ground truth holds no evaluated class")
    return float(np.nanmean(iou))

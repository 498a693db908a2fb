"""Output formats over a root: one module per format (Cityscapes, IDDA, COCO, HF) over shared frame placing, and the dataset card."""

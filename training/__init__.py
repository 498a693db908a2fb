"""Tools for people who train on the data: exports (one module per format over training.placing), loaders, analysis (may import torch; nothing below it does).

``training`` sits above ``manifests``: it reads frames through the public
reader and loaders. PyTorch comes with the optional ``analysis`` extra
(``pip install -e '.[analysis]'``); the pipeline and the renderers never need it.
"""

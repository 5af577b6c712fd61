"""neurotouch-hid: the NeuroTouch soft tactile sensor as a standard Linux game controller.

The method is Hoffmann et al., "From Soft Materials to Controllers with NeuroTouch" (the paper,
``shared/paper/neurotouch.tex``); section names cited in docstrings refer to it.
"""

__version__ = "0.1.0"

"""Enrolment: a few guided minutes in which the driver learns this gel and this hand.

One module per stage:

- ``plan.py``: the prompts (which gesture, when, how long), made from a seed, written and read as
  docs/dataset.md's "Guided session plan (JSON)";
- ``hand.py``: the simulated hand that performs a plan like a person (late, longer or shorter,
  a prompt missed now and then), on the simulated gel;
- ``label.py``: labels a recording made by following a plan (the type from the prompt, the
  moments, contacts and intensity from the gel), and writes it as a dataset (docs/dataset.md);
- ``session.py``: the guided session itself (prompts on the terminal while the camera records),
  run by the runtime (:class:`~neurotouch_hid.engine.engine.Engine`), ``prompt_view.py`` what it
  shows, a subscriber to the run;
- ``adapt.py``: the recogniser fitted to the gel and hand from enrolment datasets, checked on
  held-out prompts (``neurotouch-hid adapt``), written as ``model.py``'s model file, which ``run``,
  ``track``, ``eval`` and ``profile test`` apply (docs/method.md, "Adaptation"); the pipeline's
  records of the enrolments in ``adapt_record.py``, their replay and the fits in ``adapt_fit.py``.
"""

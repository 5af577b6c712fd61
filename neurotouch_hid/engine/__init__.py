"""The engine: source -> pipeline -> mapping -> subscribers, in threads, with clean shutdown
(:mod:`~neurotouch_hid.engine.engine`), its parts (the run's mode and options, the queues, the rest
hand-over, the publisher), what a run opens (:mod:`~neurotouch_hid.engine.assembly`) and the
``run`` and ``demo`` commands' wiring (:mod:`~neurotouch_hid.engine.driver`).
"""

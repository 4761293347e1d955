"""Experiments and probes: one-off questions about the pipeline, each run as ``python -m experiments.<name>``.

Not part of the pipeline and not benchmarks of its defaults (those are ``bench/``): each module asks one question,
and ``experiments/README.md`` gives the question, the command and where the answer is recorded. They may import
``prl``, ``envs``, ``flows`` and ``bench``; nothing else imports them, tests included (``tests/test_structure.py``).
"""

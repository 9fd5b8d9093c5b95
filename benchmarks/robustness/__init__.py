"""The sections of ``benchmarks/bench_robustness.py``, one module each (see its docstring)."""

"""Offline work: training collection and fitting, evaluation and its report, the hardware check,
the service / train / motion benchmarks, local and Ray executors."""

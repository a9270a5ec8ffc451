"""Regression runs over recorded datasets: scenario files, the stages they run, baselines and the gate.

At the top of the library (beside view, under the API and ``usvlog regress``): it runs the
same estimate, identify and replay calls as the verbs and compares their metrics with
accepted baselines.
"""

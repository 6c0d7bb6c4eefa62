"""Benchmark evaluation, as ``evaluate.py`` runs it: every agent on every task through the same ``env.step`` loop.

``benchmarks``: the benchmark tasks (the id each plays, its options, its quick and full seed counts);
``protocol``: which agents play which tasks on which seeds (``RunProtocol``, ``EpisodeSpec``); ``episodes``: one
episode's env, agent and step loop; ``runner``: a protocol's episodes in worker processes or Ray tasks, logged
as they finish and resumable; ``metrics``: rates with their intervals, and the metrics per (agent, task);
``report``: the files a run leaves (results.json, results.csv, timing.json, report.md, videos).
"""

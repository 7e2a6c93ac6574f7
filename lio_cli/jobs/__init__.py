"""One job per command: a plain, picklable description of a run -> ``run(job)`` -> a result.

No typer, rich or printing here: the CLI and the batch runner both call these entry points and decide
themselves what to show and where to write.
"""

"""One package per command, each keeping one contract (``contract.Command``): a plain, picklable job ->
``run(job)`` -> a result -> ``score(result, reference)`` where ground truth applies -> ``write(result, out)``.

No typer, rich or printing here: the CLI and the batch runner both call these entry points and decide
themselves what to show.
"""

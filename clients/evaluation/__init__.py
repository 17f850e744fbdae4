"""Evaluation on public datasets: metrics (:mod:`.metrics`), the engine harness (:mod:`.harness`) and PNG
plots (:mod:`.plots`). The command line is ``pednav eval vicon|gdin`` (:mod:`clients.commands.eval`)."""

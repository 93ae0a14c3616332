"""Declarative YAML workflows: schema, registries of models and step kinds, the runner.

Typical use is the command line (``geodem run FILE.yaml -o DIR``, ``geodem validate``,
``geodem schema``; docs/workflows.md). From Python::

    from geodem.workflow import run_workflow
    code, summary = run_workflow("workflows/two_balls.yaml", "out/two_balls")

New step kinds and model builders register themselves::

    from geodem.workflow import StepBase, register_step

    @register_step("my_step")
    class MyStep(StepBase):
        ...
"""
from geodem.workflow.errors import ErrorItem, Interrupted, RunFailure, WorkflowError
from geodem.workflow.schema import (
    MODELS,
    STEPS,
    ModelBase,
    StepBase,
    json_schema,
    register_model,
    register_step,
    workflow_model,
)


def run_workflow(*args, **kwargs):
    """See :func:`geodem.workflow.runner.run_workflow`."""
    from geodem.workflow.runner import run_workflow as _run

    return _run(*args, **kwargs)


def prepare(*args, **kwargs):
    """See :func:`geodem.workflow.runner.prepare`."""
    from geodem.workflow.runner import prepare as _prepare

    return _prepare(*args, **kwargs)


__all__ = ["ErrorItem", "Interrupted", "RunFailure", "WorkflowError", "MODELS", "STEPS",
           "ModelBase", "StepBase", "json_schema", "register_model", "register_step",
           "workflow_model", "run_workflow", "prepare"]

"""The robot a job describes: a design space's design, decoded and written as URDF, or a
template expanded at the job's params. Light on purpose: function runners use it too."""

from __future__ import annotations

from adclient.design import DesignSpace
from adclient.designs import Design
from adclient.schemas import Job, TemplateSpace
from adworker.runner import JobError


def job_robot(job: Job) -> tuple[Design | None, str]:
    """The job's design and URDF: a design space's decoded and written, or a template
    study's robot with no design: the URDF the server expanded once (``job.urdf``), or,
    for a trial stored before the server kept URDFs, the template expanded here at the
    job's params (in a child process)."""
    from adclient.templates import TemplateError, expand_isolated
    from adclient.urdf import design_to_urdf

    if isinstance(job.space, TemplateSpace):
        if job.urdf is not None:
            return None, job.urdf
        try:
            (urdf,) = expand_isolated(job.space.template, [job.params])
        except TemplateError as error:
            raise JobError(str(error)) from None
        return None, urdf
    design = decode_job(job)
    return design, design_to_urdf(design, robot_name="robot")


def decode_job(job: Job) -> Design:
    from adclient.decode import decode, identity_representation

    if not isinstance(job.space, DesignSpace):
        raise JobError(
            f"task {job.task.name!r} needs a design space (type: design) or a template; "
            f"this study's space is of type {job.space.type!r}"
        )
    representation = job.representation or identity_representation(job.space)
    return decode(job.space, representation, job.vector)

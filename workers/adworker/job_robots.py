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
    job's params (in a child process). A template's URDF is checked before anything
    reads it (:func:`checked_urdf`): whatever an older server stored, no engine is
    handed one that is not data, too large, or names a file."""
    from adclient.templates import TemplateError, expand_isolated
    from adclient.urdf import design_to_urdf

    if isinstance(job.space, TemplateSpace):
        if job.urdf is not None:
            return None, checked_urdf(job.urdf)
        try:
            (urdf,) = expand_isolated(job.space.template, [job.params])
        except TemplateError as error:
            raise JobError(str(error)) from None
        return None, checked_urdf(urdf)
    design = decode_job(job)
    return design, design_to_urdf(design, robot_name="robot")


def checked_urdf(urdf: str) -> str:
    """A template's URDF, if it is one the worker builds: within ``MAX_URDF_BYTES`` and
    a robot :func:`adclient.urdf_model.read_urdf` reads (XML as data, primitive shapes
    only, visual and collision alike); JobError naming the problem otherwise."""
    from adclient.templates import MAX_URDF_BYTES
    from adclient.urdf_model import URDFModelError, read_urdf

    size = len(urdf.encode())
    if size > MAX_URDF_BYTES:
        raise JobError(f"the robot's URDF is {size:,} bytes, over the worker's {MAX_URDF_BYTES:,}")
    try:
        read_urdf(urdf)
    except URDFModelError as error:
        raise JobError(f"the robot's URDF builds no robot: {error}") from None
    return urdf


def decode_job(job: Job) -> Design:
    from adclient.decode import decode, identity_representation

    if not isinstance(job.space, DesignSpace):
        raise JobError(
            f"task {job.task.name!r} needs a design space (type: design) or a template; "
            f"this study's space is of type {job.space.type!r}"
        )
    representation = job.representation or identity_representation(job.space)
    return decode(job.space, representation, job.vector)


def check_buildable(job: Job, design: Design | None) -> None:
    """A JobError naming the links of ``design`` that interpenetrate at its rest pose
    (``adclient.overlaps``), where its space says they may not (``allow_overlaps:
    false``, what the server stores for a new study): such a design's trial fails before
    any simulation. A study stored before the check (null) is evaluated as it was; a
    template's robot is not checked."""
    from adclient.overlaps import overlap_reason, rest_overlaps

    if design is None or not isinstance(job.space, DesignSpace):
        return
    if job.space.allow_overlaps is not False:
        return
    found = rest_overlaps(design)
    if found:
        raise JobError(
            f"{overlap_reason(found)}: the design cannot be built (the study's space may "
            "allow it: allow_overlaps: true)"
        )

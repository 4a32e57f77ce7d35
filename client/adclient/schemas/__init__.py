"""The HTTP contract: every request and response body of the v1 API.

These pydantic models are the one source of truth shared by the server (which
validates and serialises with them) and by the SDK and workers (which parse with
them). Fields may be added; the paths, names and codes of v1 stay.

What every body shares (limits, states, checks of free JSON) is in ``common``; the
search space in ``space``; proposer and task configuration in ``config``; the bodies of
``studies``, ``trials``, ``workers`` (leases, jobs, artifacts), ``auth`` and ``errors``
in their modules; a trial's learning curve (its ``curve.json`` artifact) in ``curves``, its
replayable evaluation episode (``replay.json``) in ``replays``.
Import from this package: its names are the contract.
"""

from __future__ import annotations

from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.objectives import (
    MAX_CONSTRAINTS,
    MAX_OBJECTIVES,
    Constraint,
    Direction,
    Objective,
    Outcomes,
    outcomes_of,
)
from adclient.plugins import PluginError, catalogue
from adclient.pruning import Checkpoint, PrunerConfig
from adclient.schemas.auth import SessionInfo, SignInRequest
from adclient.schemas.common import (
    CUT_JSON,
    MAX_ASK,
    MAX_JSON_BYTES,
    MAX_JSON_DEPTH,
    MAX_STUDY_NAME,
    MAX_TRIAL_PAGE,
    MAX_USER_ATTR_KEY,
    MAX_USER_ATTRS_BYTES,
    MAX_WORKER_PAGE,
    NAME_PATTERN,
    NO_NUL_PATTERN,
    JsonObject,
    StoredJsonObject,
    StudyName,
    StudyState,
    TrialState,
    UserAttrs,
    bounded_user_attrs,
    study_name,
)
from adclient.schemas.config import (
    LearnerInfo,
    NewProposerConfig,
    NewTaskConfig,
    ProposerConfig,
    TaskConfig,
    TaskInfo,
    option_problems,
)
from adclient.schemas.curves import CURVE_ARTIFACT, Curve, EvaluationEpisode, TrainPoint
from adclient.schemas.errors import ErrorBody
from adclient.schemas.notes import MAX_NOTE_CHARS, Note, NoteUpdate
from adclient.schemas.replays import REPLAY_ARTIFACT, Replay
from adclient.schemas.space import (
    MAX_CHOICES,
    MAX_STEPS,
    BoxParam,
    BoxSpace,
    Choice,
    Space,
    TemplateSpace,
)
from adclient.schemas.studies import (
    ONE_DESIGN_REPEATS,
    ObjectiveName,
    ObjectiveSpread,
    Study,
    StudyCreate,
    StudySpread,
    StudyUpdate,
)
from adclient.schemas.trials import (
    MAX_TRIALS_ADDED,
    AskRequest,
    AskResponse,
    Spawn,
    StudyCurves,
    TellRequest,
    Trial,
    TrialAdd,
    TrialAddBody,
    TrialAdds,
    TrialColumns,
    TrialCurve,
    TrialUpdate,
)
from adclient.schemas.workers import (
    SHARED_ARTIFACT,
    ArtifactInfo,
    HeartbeatRequest,
    HeartbeatResponse,
    Job,
    LeaseRequest,
    ReleaseRequest,
    SharedUpdate,
    SharedVersion,
    StudyServing,
    TransferSource,
    WorkerInfo,
)

__all__ = [
    "CURVE_ARTIFACT",
    "CUT_JSON",
    "MAX_ASK",
    "MAX_CHOICES",
    "MAX_CONSTRAINTS",
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MAX_NOTE_CHARS",
    "MAX_OBJECTIVES",
    "MAX_STEPS",
    "MAX_STUDY_NAME",
    "MAX_TRIALS_ADDED",
    "MAX_TRIAL_PAGE",
    "MAX_USER_ATTRS_BYTES",
    "MAX_USER_ATTR_KEY",
    "MAX_WORKER_PAGE",
    "NAME_PATTERN",
    "NO_NUL_PATTERN",
    "ONE_DESIGN_REPEATS",
    "REPLAY_ARTIFACT",
    "SHARED_ARTIFACT",
    "ArtifactInfo",
    "AskRequest",
    "AskResponse",
    "BoxParam",
    "BoxSpace",
    "Checkpoint",
    "Choice",
    "Constraint",
    "Curve",
    "DesignSpace",
    "Direction",
    "ErrorBody",
    "EvaluationEpisode",
    "HeartbeatRequest",
    "HeartbeatResponse",
    "Job",
    "JsonObject",
    "LearnerInfo",
    "LeaseRequest",
    "NewProposerConfig",
    "NewTaskConfig",
    "Note",
    "NoteUpdate",
    "Objective",
    "ObjectiveName",
    "ObjectiveSpread",
    "Outcomes",
    "PluginError",
    "ProposerConfig",
    "PrunerConfig",
    "ReleaseRequest",
    "Replay",
    "Representation",
    "SessionInfo",
    "SharedUpdate",
    "SharedVersion",
    "SignInRequest",
    "Space",
    "Spawn",
    "StoredJsonObject",
    "Study",
    "StudyCreate",
    "StudyCurves",
    "StudyName",
    "StudyServing",
    "StudySpread",
    "StudyState",
    "StudyUpdate",
    "TaskConfig",
    "TaskInfo",
    "TellRequest",
    "TemplateSpace",
    "TrainPoint",
    "TransferSource",
    "Trial",
    "TrialAdd",
    "TrialAddBody",
    "TrialAdds",
    "TrialColumns",
    "TrialCurve",
    "TrialState",
    "TrialUpdate",
    "UserAttrs",
    "WorkerInfo",
    "bounded_user_attrs",
    "catalogue",
    "option_problems",
    "outcomes_of",
    "study_name",
]

"""The arm controller in a bag's run metadata: the entries a recording writes
(`arm_controller_metadata`) and the `ArmController` a reader rebuilds from them, checked."""
from __future__ import annotations

from mobile_manip_sim.scene import schema
from mobile_manip_sim.scene.arm_controller import (
    DEFAULT_FEEDFORWARD,
    EFFORT,
    GAINS,
    MODES,
    ArmController,
    ModelError,
)
from mobile_manip_sim.scene.errors import UserError

MODEL_ERROR_FIELDS = ("mass", "inertia", "payload")   # `ModelError`'s, when not the default


def arm_controller_metadata(controller) -> dict:
    """The metadata entries of an `ArmController` resolved for its robot: none in effort mode
    (such a bag is what it was before arm controllers existed); the model error's only when the
    feed-forward's model is not the plant's."""
    if not controller.active:
        return {}
    entries = {"arm_controller": controller.mode, "arm_feedforward": controller.feedforward,
               **{f"arm_{name}": " ".join(repr(float(v)) for v in getattr(controller, name))
                  for name in GAINS}}
    error = controller.model_error
    for name in MODEL_ERROR_FIELDS:
        value = getattr(error, name)
        if value != getattr(ModelError(), name):
            entries[f"arm_model_error_{name}"] = repr(float(value))
    return entries


def arm_controller_from_metadata(value: dict, path: str):
    """The `ArmController` a bag's metadata records (effort mode without arm_controller)."""
    mode = value.get("arm_controller", EFFORT)
    if mode not in MODES:
        raise UserError(f"{path}.arm_controller", f"unknown mode {schema.short(mode)} (choose "
                                                  f"one of: {', '.join(MODES)})")
    if not MODES[mode].controlled:
        return ArmController()
    gains = []
    for name in GAINS:
        key = f"arm_{name}"
        if key not in value:
            raise UserError(f"{path}.{key}", f"missing (arm_controller {mode} records its "
                                             f"gains)")
        try:
            gains.append(tuple(float(v) for v in value[key].split()))
        except ValueError:
            raise UserError(f"{path}.{key}", f"expected numbers, got "
                                             f"{schema.short(value[key])}") from None
    error = {}
    for name in MODEL_ERROR_FIELDS:
        key = f"arm_model_error_{name}"
        if key in value:
            try:
                error[name] = float(value[key])
            except ValueError:
                raise UserError(f"{path}.{key}", f"expected a number, got "
                                                 f"{schema.short(value[key])}") from None
    try:
        return ArmController(mode, *gains, value.get("arm_feedforward", DEFAULT_FEEDFORWARD),
                             ModelError(**error))
    except UserError as error:
        raise UserError(f"{path}.{error.key}", error.problem) from None


def check_gain_counts(controller, n_arm: int, path: str) -> None:
    """A bag records its controller's gains resolved: one per arm joint of its scene."""
    for name in GAINS if controller.active else ():
        if len(getattr(controller, name)) != n_arm:
            raise UserError(f"{path}.arm_{name}", f"expected {n_arm} numbers (one per "
                                                           f"arm joint of the bag's scene), got "
                                                           f"{len(getattr(controller, name))}")

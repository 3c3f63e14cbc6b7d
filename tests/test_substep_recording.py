"""The one substep hook: rows of the live simulation taken inside ``frame_skip``, the environment left untouched."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from smo_gym.wrappers.adapters import SubstepRecording, make_adapter


def _pair(seed: int = 0):
    """Two identical Hopper-v5 simulations (frame_skip 4), reset from the same seed."""
    envs = [gym.make("Hopper-v5").unwrapped for _ in range(2)]
    for env in envs:
        env.reset(seed=seed)
    return envs


def _reference_rows(env, action, every: int) -> tuple[np.ndarray, np.ndarray]:
    """qpos and qvel after every ``every``-th physics step of one environment step, by stepping MuJoCo by hand."""
    env.data.ctrl[:] = action
    qpos, qvel = [], []
    for k in range(1, env.frame_skip + 1):
        mujoco.mj_step(env.model, env.data)
        if k % every == 0:
            qpos.append(env.data.qpos.copy())
            qvel.append(env.data.qvel.copy())
    mujoco.mj_rnePostConstraint(env.model, env.data)
    return np.array(qpos), np.array(qvel)


@pytest.mark.parametrize("every", [1, 2, 4])
def test_rows_are_the_physics_steps_and_grow_past_their_capacity(every):
    env, reference = _pair()
    recording = SubstepRecording(every, {"qpos": env.model.nq, "qvel": env.model.nv}, capacity=1)
    hook = make_adapter(env).record_substeps(recording)
    action = np.full(env.action_space.shape, 0.3)
    for _ in range(3):  # the buffers hold one row at first: the hook grows them
        recording.start()
        with hook:
            env.step(action)
        expected_qpos, expected_qvel = _reference_rows(reference, action, every)
        np.testing.assert_array_equal(recording.rows["qpos"][: recording.n], expected_qpos)
        np.testing.assert_array_equal(recording.rows["qvel"][: recording.n], expected_qvel)
    assert recording.n == env.frame_skip // every
    # the hooked trajectory is the unhooked one, bit for bit
    np.testing.assert_array_equal(env.data.qpos, reference.data.qpos)
    np.testing.assert_array_equal(env.data.qvel, reference.data.qvel)


def test_the_hook_is_removed_on_exit_and_on_an_exception():
    env, _ = _pair()
    recording = SubstepRecording(1, {"qpos": env.model.nq}, capacity=4)
    hook = make_adapter(env).record_substeps(recording)
    assert "_step_mujoco_simulation" not in vars(env)
    with hook:
        assert "_step_mujoco_simulation" in vars(env)
    assert "_step_mujoco_simulation" not in vars(env)
    with pytest.raises(ZeroDivisionError), hook:
        1 / 0
    assert "_step_mujoco_simulation" not in vars(env)


def test_a_partial_count_carries_over_to_the_next_call():
    """With ``every`` not dividing the steps of one call, the count continues into the next call (and the row
    already taken is kept when the buffer grows)."""
    env, reference = _pair()
    recording = SubstepRecording(3, {"qpos": env.model.nq}, capacity=1)
    hook = make_adapter(env).record_substeps(recording)
    action = np.zeros(env.action_space.shape)
    recording.start()
    with hook:
        env.step(action)  # 4 physics steps: one row (after the 3rd), count 1
        env.step(action)  # 4 more: a row after the 6th physics step, count 2
    assert (recording.n, recording.count) == (2, 2)
    expected = []
    for k in range(1, 9):
        reference.data.ctrl[:] = action
        mujoco.mj_step(reference.model, reference.data)
        if k % 3 == 0:
            expected.append(reference.data.qpos.copy())
    np.testing.assert_array_equal(recording.rows["qpos"][:2], np.array(expected))

"""trainer.tasks.terms: the reward's table of named terms (the paper's reward and its ablations
as configurations of it), its sum, and the observation keys the specs are made from."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from trainer.config import REWARDS, EnvConfig, RewardConfig
from trainer.tasks import terms
from trainer.tasks.spec import observation_spec


def _quantities(n: int = 64) -> terms.StepQuantities:
    gen = torch.Generator().manual_seed(3)
    tip_distance = torch.rand(n, 5, generator=gen) * 0.2 - 0.02  # some pads pressed in
    tip_distance[0] = float("nan")  # a blown-up env
    return terms.StepQuantities(
        lift=torch.rand(n, generator=gen) * 0.3,
        h_bar=torch.full((n,), 0.2),
        success=torch.rand(n, generator=gen) > 0.7,
        tips=torch.rand(n, 5, 3, generator=gen),
        tip_distance=tip_distance,
        obj_pos=torch.rand(n, 3, generator=gen),
    )


def _paper(r: RewardConfig, q: terms.StepQuantities) -> dict[str, torch.Tensor]:
    """The reward as the task computed it before the table (the paper's formula, in its order)."""
    lift = r.c1 / ((q.h_bar - q.lift).abs() + r.eps_h)
    success = r.c2 * q.success.float()
    if r.kind == "none":
        contact = torch.zeros_like(q.lift)
    elif r.kind == "sdf":
        contact = r.c3 / (q.tip_distance.clamp_min(0.0).sum(-1) + r.eps_sdf)
    elif r.kind == "sdf-thumb":  # not the paper's: the thumb and the nearest finger
        d = q.tip_distance.clamp_min(0.0)
        contact = r.c3 / (d[:, 0] + d[:, 1:].min(-1).values + r.eps_sdf)
    else:
        contact = r.c3 / ((q.tips - q.obj_pos[:, None, :]).norm(dim=-1).sum(-1) + r.eps_sdf)
    return {"lift": lift, "success": success, "contact": contact}


@pytest.mark.parametrize("kind", REWARDS)
def test_table_is_the_papers_reward_bit_for_bit(kind: str) -> None:
    r = RewardConfig(kind=kind, c1=0.7, c2=123.0, c3=1.3)
    q = _quantities()
    values = terms.evaluate_terms(terms.reward_terms(r), q, r)
    expected = _paper(r, q)
    assert list(values) == ["lift", "success", "contact"]
    for name in expected:
        assert torch.equal(values[name].nan_to_num(-1.0), expected[name].nan_to_num(-1.0)), name
    summed = expected["lift"] + expected["success"] + expected["contact"]
    total = terms.total_reward(values)
    assert torch.equal(total, torch.nan_to_num(summed, nan=0.0, posinf=0.0, neginf=0.0))
    assert total.isfinite().all()


def test_every_reward_kind_has_a_contact_variant() -> None:
    assert set(terms.CONTACT_VARIANTS) == set(REWARDS)


def test_thumb_variant_pays_a_pinch_fully_and_a_rest_without_the_thumb_less() -> None:
    """``sdf-thumb``: a thumb-index pinch (other pads 5 cm off) earns 1 / eps_sdf, as much as
    five pads on the surface; four fingers resting on the object with the thumb 4 cm off earn
    less. The paper's five-pad sum pays the pinch less than that rest."""
    pinch = [0.0, 0.0, 0.05, 0.05, 0.05]
    rest = [0.04, 0.0, 0.0, 0.0, 0.0]
    everything = [0.0] * 5
    q = _quantities(3)._replace(tip_distance=torch.tensor([pinch, rest, everything]))
    thumb = RewardConfig(kind="sdf-thumb")
    paper = RewardConfig(kind="sdf")
    by_thumb = terms.evaluate_terms(terms.reward_terms(thumb), q, thumb)["contact"]
    by_paper = terms.evaluate_terms(terms.reward_terms(paper), q, paper)["contact"]
    torch.testing.assert_close(by_thumb[0], by_thumb[2])
    torch.testing.assert_close(by_thumb[0], torch.tensor(1.0 / thumb.eps_sdf))
    assert by_thumb[1] < by_thumb[0]
    assert by_paper[0] < by_paper[1]


def test_ablation_without_contact_is_zero_whatever_the_weight() -> None:
    r = RewardConfig(kind="none", c3=5.0)
    q = _quantities()
    assert (terms.evaluate_terms(terms.reward_terms(r), q, r)["contact"] == 0).all()


def test_weights_come_from_the_config() -> None:
    r = RewardConfig(c1=0.0, c2=2.0, c3=0.0)
    q = _quantities()
    values = terms.evaluate_terms(terms.reward_terms(r), q, r)
    assert (values["lift"] == 0).all() and (values["contact"][1:] == 0).all()
    assert torch.equal(values["success"], 2.0 * q.success.float())


def test_sum_adds_in_table_order() -> None:
    # Three float32 values whose sum depends on the order: (a + b) + c != a + (b + c).
    a, b, c = torch.tensor([1e8]), torch.tensor([-1e8]), torch.tensor([1.0])
    assert terms.total_reward({"a": a, "b": b, "c": c}) == (a + b) + c
    assert terms.total_reward({"b": b, "c": c, "a": a}) == (b + c) + a
    assert (a + b) + c != (b + c) + a


@pytest.mark.parametrize(
    ("task", "representation", "context"),
    [("lift", "sdf", "none"), ("lift", "pc128", "none"), ("bin", "bbox", "bbox")],
)
def test_specs_come_from_the_tables(task: str, representation: str, context: str) -> None:
    cfg = EnvConfig(task=task, representation=representation, context=context)
    spec = observation_spec(cfg, num_envs=4)["observation"]
    declared = terms.observation_terms(cfg)
    reward_keys = [terms.reward_output_key(n) for n in terms.reward_terms(cfg.reward)]
    assert reward_keys == ["reward_lift", "reward_success", "reward_contact"]
    assert set(spec.keys()) == {t.name for t in declared} | set(reward_keys) | {
        "success", "unstable", "grasp_start", "lift_height", "object_id"
    }
    for term in declared:
        assert spec[term.name].shape == (4, *term.shape(cfg))
        assert spec[term.name].dtype == term.dtype
    names = [t.name for t in declared]
    assert names[:2] == ["proprio", "object"]
    assert ("context" in names) == (context == "bbox")


def test_an_added_term_reaches_the_reward_and_the_specs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Adding a term to the table is the whole change: its value is summed and logged, its
    output gets a spec."""
    table = terms.reward_terms

    def per_step(weight: float, q: terms.StepQuantities, r: RewardConfig) -> torch.Tensor:
        return torch.full_like(q.lift, weight)

    def with_time_penalty(r: RewardConfig) -> dict[str, terms.RewardTerm]:
        return {**table(r), "time": terms.RewardTerm(-0.5, per_step)}

    monkeypatch.setattr(terms, "reward_terms", with_time_penalty)
    from trainer.tasks import spec as spec_module

    monkeypatch.setattr(spec_module, "reward_terms", with_time_penalty)
    cfg = dataclasses.replace(EnvConfig(), reward=RewardConfig(kind="com"))
    assert "reward_time" in list(observation_spec(cfg, 2)["observation"].keys())
    q = _quantities(8)
    values = terms.evaluate_terms(terms.reward_terms(cfg.reward), q, cfg.reward)
    expected = _paper(cfg.reward, q)
    total = expected["lift"] + expected["success"] + expected["contact"] - 0.5
    assert torch.equal(terms.total_reward(values), total)

"""MCP + model-free (issue 19): how good is the dynamics model, and how well does its MPC drive?

Builds the pieces of the MCP + MF baseline (docs/baselines.md) outside the trainer and
measures them in one arena (default ``training``):

1. data: ``--random-episodes`` with uniform random actions and ``--advisor-episodes`` with the
   advisor (Alg. A1) plus OU noise (θ 0.15, σ 0.1), as the agent's prior phases execute it;
2. the model (``agent/dynamics_model.py``, hidden ``--hidden``; also ``--compare-hidden``)
   fitted for ``--model-steps`` Adam steps, normaliser from the random episodes (frozen);
   optionally ``--rounds`` of on-policy aggregation: ``--round-episodes`` MPC episodes, added
   to the data, refit (the agent's schedule is 4 × 40 with no advisor episodes);
3. its one- and multi-step (``--horizons``) open-loop prediction error of the 20-d observation
   on held-out episodes (fresh keys: random, advisor, and the MPC's own evaluation episodes),
   per group (P RMSE m, mean |error| of δ rad and d m, v RMSE m/s), beside the zero-change
   predictor ŝ_{t+k} = s_t;
4. the random-shooting MPC (``agent/mpc.py``; ``--candidates`` K, ``--horizon`` H, clean first
   action, Eq. 8 from predicted observations) over ``--mpc-episodes`` episodes, next to the
   deterministic advisor on the same starts and goals (``evaluation/evaluate.py``), paired.

Writes ``<out>.json`` and ``<out>.md`` (command, device, date). Defaults are the GPU run of
docs/baselines.md (K 1,000, H 20, 500 episodes; estimated ~5 min on one H100 with compiles,
add ~1 min for ``--rounds 4``; the agent's own model: ``--advisor-episodes 0 --rounds 4``).
A CPU smoke run (about 2 min on 2 cores, mostly compiling; numbers meaningless, do not commit):

    python experiments/mcp_model_quality.py --random-episodes 4 --advisor-episodes 4 \\
        --heldout-episodes 3 --max-episode-steps 30 --hidden 32 32 --compare-hidden \\
        --model-steps 60 --batch 64 --horizons 1 5 --candidates 16 --horizon 4 \\
        --mpc-episodes 4 --rounds 1 --round-episodes 2 --out /tmp/mcp_smoke
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

import envs
from advisor_jax.agent.advisor import advisor_action, arena_advisor
from advisor_jax.agent.dynamics_model import make_dynamics_model, normalizer_from_data
from advisor_jax.agent.mpc import make_mpc_policy, sample_candidates
from advisor_jax.agent.noise import ou_init, ou_reset, ou_step
from advisor_jax.agent.replay_buffer import Transition
from advisor_jax.bench import measure, writing
from advisor_jax.contract import spec
from advisor_jax.evaluation.evaluate import EvalMetrics, make_evaluate, summary
from advisor_jax.fileio import atomic_write_json

OU_THETA, OU_SIGMA = 0.15, 0.1  # HParams defaults (agent/config.py), R16
CHUNK = 25  # env steps per jitted call: progress and an early stop once every episode ended
FIT_CHUNK = 250  # model steps per jitted call


# -- rollouts: the first episode of each of n envs, recorded --------------------------------


@struct.dataclass
class Carry:
    env: Any  # NavState [n]
    noise: Any  # OUState [n, 2]
    alive: jax.Array  # [n] still in its first episode
    outcome: jax.Array  # [n] of the first episode (0 while it runs)
    length: jax.Array
    episode_return: jax.Array
    collision_speed: jax.Array
    key: jax.Array


def make_runner(env, act: Callable, n_envs: int, ou_sigma: float):
    """``(start(reset_key, key) -> Carry, run(params, carry) -> (carry, records))``.

    ``act(params, obs [n, 20], key) -> actions [n, 2]``. Resets from ``split(reset_key, n)``,
    as ``make_evaluate`` does, so runs with the same reset key share starts and goals.
    Records per step: (obs, action, s' before reset, alive before the step)."""
    low = jnp.asarray(spec.ACTION_LOW, jnp.float32)
    high = jnp.asarray(spec.ACTION_HIGH, jnp.float32)

    def start(reset_key, key) -> Carry:
        zf, zi = jnp.zeros(n_envs, jnp.float32), jnp.zeros(n_envs, jnp.int32)
        return Carry(
            env=jax.vmap(env.reset)(jax.random.split(reset_key, n_envs)),
            noise=ou_init((n_envs, spec.ACTION_SIZE)),
            alive=jnp.ones(n_envs, bool),
            outcome=zi,
            length=zi,
            episode_return=zf,
            collision_speed=zf,
            key=key,
        )

    def body(params, c: Carry, _):
        key, k_act, k_noise = jax.random.split(c.key, 3)
        obs = c.env.obs
        action = act(params, obs, k_act)
        noise, x = ou_step(c.noise, k_noise, OU_THETA, ou_sigma)
        if ou_sigma > 0:
            action = jnp.clip(action + x, low, high)
        new = jax.vmap(env.step)(c.env, action)
        ended = c.alive & new.done
        pick = lambda now, old: jnp.where(ended, now, old)  # noqa: E731
        c2 = Carry(
            env=new,
            noise=ou_reset(noise, new.done),
            alive=c.alive & ~new.done,
            outcome=pick(new.outcome, c.outcome),
            length=pick(new.episode_length, c.length),
            episode_return=pick(new.episode_return, c.episode_return),
            collision_speed=pick(new.collision_speed, c.collision_speed),
            key=key,
        )
        return c2, (obs, action, new.terminal_obs, c.alive)

    @jax.jit
    def run(params, carry):
        return jax.lax.scan(lambda c, x: body(params, c, x), carry, None, length=CHUNK)

    return jax.jit(start), run


_RUNNERS: dict[tuple, tuple] = {}  # one compile per (controller, envs, noise)


def play(progress, label, env, act, params, n_envs, reset_key, key, ou_sigma=0.0) -> dict:
    """Runs the first episode of ``n_envs`` envs; trajectories [T, n] and episode results."""
    if (act, n_envs, ou_sigma) not in _RUNNERS:
        _RUNNERS[act, n_envs, ou_sigma] = make_runner(env, act, n_envs, ou_sigma)
    start, run = _RUNNERS[act, n_envs, ou_sigma]
    carry = start(reset_key, key)
    task = progress.add_task(label, total=env.max_episode_steps)
    records, steps = [], 0
    while steps < env.max_episode_steps and bool(jnp.any(carry.alive)):
        carry, rec = run(params, carry)
        records.append(jax.device_get(rec))
        steps += CHUNK
        progress.update(task, completed=min(steps, env.max_episode_steps))
    progress.update(task, completed=env.max_episode_steps)
    obs, action, next_obs, valid = (np.concatenate(x) for x in zip(*records, strict=True))
    metrics = EvalMetrics(
        outcome=carry.outcome,
        length=carry.length,
        episode_return=carry.episode_return,
        collision_speed=carry.collision_speed,
    )
    return dict(obs=obs, action=action, next_obs=next_obs, valid=valid, metrics=metrics)


def flat(trajs: list[dict]) -> Transition:
    """The valid transitions of several trajectories, as a replay-like Transition."""
    pick = {f: np.concatenate([t[f][t["valid"]] for t in trajs]) for f in ("obs", "action")}
    nxt = np.concatenate([t["next_obs"][t["valid"]] for t in trajs])
    zeros = np.zeros(len(nxt), np.float32)
    return Transition(
        obs=pick["obs"],
        action=pick["action"],
        advisor_action=pick["action"],
        reward=zeros,
        next_obs=nxt,
        terminal=zeros,
    )


# -- the model: fit and errors --------------------------------------------------------------


def fit(progress, label, model, state, data: Transition, key, args) -> tuple[Any, list[float]]:
    fit_chunk = jax.jit(model.fit, static_argnames=("steps", "batch_size"))
    count = len(data.obs)
    task = progress.add_task(label, total=args.model_steps)
    losses, done = [], 0
    while done < args.model_steps:
        n = min(FIT_CHUNK, args.model_steps - done)
        key, k = jax.random.split(key)
        state, chunk_losses = fit_chunk(
            state, data, count, k, args.model_lr, args.model_noise, n, args.batch
        )
        losses.append(float(np.mean(np.asarray(chunk_losses)[-max(1, n // 5) :])))
        done += n
        progress.update(task, completed=done)
    return state, losses


def kstep_errors(model, params, norm, traj: dict, horizons: list[int]) -> dict:
    """Open-loop errors at each horizon k over every window inside a first episode."""
    obs, act, nxt, valid = traj["obs"], traj["action"], traj["next_obs"], traj["valid"]
    steps, n = valid.shape
    kmax = max(horizons)
    pad = lambda x: np.concatenate([x, np.zeros((kmax, *x.shape[1:]), x.dtype)])  # noqa: E731
    act_p, nxt_p, valid_p = pad(act), pad(nxt), pad(valid)
    t0, env_i = np.nonzero(valid)  # every start inside a first episode
    window = t0[:, None] + np.arange(kmax)  # [S, kmax]
    rollout = jax.jit(jax.vmap(model.rollout, in_axes=(None, None, 0, 0)))
    preds = np.concatenate(
        [
            np.asarray(
                rollout(params, norm, obs[t0[s], env_i[s]], act_p[window[s], env_i[s, None]])
            )
            for s in np.array_split(np.arange(len(t0)), max(1, math.ceil(len(t0) / 4096)))
        ]
    )  # [S, kmax, 20]
    out = {}
    for k in horizons:
        ok = valid_p[t0 + k - 1, env_i]
        target = nxt_p[t0 + k - 1, env_i][ok]
        rows = {"model": preds[ok, k - 1], "zero_change": obs[t0, env_i][ok]}
        out[str(k)] = {"windows": int(ok.sum())} | {
            name: group_errors(pred, target) for name, pred in rows.items()
        }
    return out


def group_errors(pred: np.ndarray, target: np.ndarray) -> dict[str, float | None]:
    if len(target) == 0:
        return {"P_rmse": None, "delta_mae": None, "d_mae": None, "v_rmse": None}
    err = pred - target
    d_delta = (err[:, spec.OBS_GOAL_ANGLE] + np.pi) % (2 * np.pi) - np.pi
    return {
        "P_rmse": float(np.sqrt(np.mean(err[:, spec.OBS_PROXIMITY] ** 2))),
        "delta_mae": float(np.mean(np.abs(d_delta))),
        "d_mae": float(np.mean(np.abs(err[:, spec.OBS_GOAL_DISTANCE]))),
        "v_rmse": float(np.sqrt(np.mean(err[:, spec.OBS_VELOCITY] ** 2))),
    }


# -- main -----------------------------------------------------------------------------------


def parse_args(argv=None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    a = p.add_argument
    a("--arena", default="training", help="arena of every episode (default %(default)s)")
    a("--max-episode-steps", type=int, default=0, help="h_max; 0: the arena's (300)")
    a("--seed", type=int, default=0, help="seed of every key (default %(default)s)")
    a("--random-episodes", type=int, default=50, help="uniform random-action episodes")
    a("--advisor-episodes", type=int, default=50, help="advisor + OU noise episodes")
    a("--heldout-episodes", type=int, default=50, help="held-out episodes per source")
    a("--hidden", type=int, nargs="+", default=[500, 500], help="model hidden widths")
    a(
        "--compare-hidden",
        type=int,
        nargs="*",
        default=[500],
        help="widths of a second model fitted on the same data; none: no second model",
    )
    a("--model-steps", type=int, default=3000, help="Adam steps per fit (default %(default)s)")
    a("--batch", type=int, default=512, help="model minibatch (default %(default)s)")
    a("--model-lr", type=float, default=1e-3, help="model Adam learning rate")
    a("--model-noise", type=float, default=0.01, help="input noise std, normalised units")
    a("--rounds", type=int, default=0, help="MPC aggregation rounds (agent: 4)")
    a("--round-episodes", type=int, default=40, help="MPC episodes per round (agent: 40)")
    a("--horizons", type=int, nargs="+", default=[1, 5, 10, 20, 50], help="k of the k-step errors")
    a("--candidates", type=int, default=1000, help="MPC candidate sequences K")
    a("--horizon", type=int, default=20, help="MPC horizon H (steps)")
    a("--mpc-episodes", type=int, default=500, help="episodes of the MPC and the advisor")
    a("--out", default="results/mcp_model_quality", help="output path without extension")
    args = p.parse_args(argv)
    counts = (
        "random_episodes",
        "heldout_episodes",
        "model_steps",
        "batch",
        "candidates",
        "horizon",
        "mpc_episodes",
        "round_episodes",
    )
    for name in counts:
        if getattr(args, name) <= 0:
            p.error(
                f"--{name.replace('_', '-')} must be a positive integer, got {getattr(args, name)}"
            )
    for name in ("advisor_episodes", "rounds", "max_episode_steps"):
        if getattr(args, name) < 0:
            p.error(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
    if min(args.horizons) <= 0 or min(args.hidden + (args.compare_hidden or [1])) <= 0:
        p.error(f"--horizons and widths must be positive, got {args.horizons}, {args.hidden}")
    return p, args


def main(argv=None) -> dict:
    parser, args = parse_args(argv)
    t_start = time.perf_counter()
    env = envs.make_env(args.arena, max_episode_steps=args.max_episode_steps)
    adv_params = arena_advisor(env)
    keys = iter(jax.random.split(jax.random.PRNGKey(args.seed), 64))
    models = {"main": tuple(args.hidden)}
    if args.compare_hidden:
        models["compare"] = tuple(args.compare_hidden)

    def random_act(_, obs, key):
        return sample_candidates(key, obs.shape[0], 1)[:, 0]

    def advisor_act(params, obs, _):
        return jax.vmap(advisor_action, in_axes=(0, None))(obs, params)

    policy = None  # the MPC of the main model, once it exists

    def mpc_act(params, obs, key):  # params: (model params, normaliser)
        return jax.vmap(policy, in_axes=(None, None, 0, 0))(
            *params, obs, jax.random.split(key, obs.shape[0])
        )

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    with Progress(*columns, TimeElapsedColumn(), transient=False) as progress:

        def episodes(label, act, params, n, sigma=0.0, reset_key=None, key=None):
            reset_key = next(keys) if reset_key is None else reset_key
            key = next(keys) if key is None else key
            return play(progress, label, env, act, params, n, reset_key, key, sigma)

        def refit(label, model, state, data):
            return (model, *fit(progress, label, model, state, data, next(keys), args))

        n_r, n_a, n_h = args.random_episodes, args.advisor_episodes, args.heldout_episodes
        train = [episodes("random episodes", random_act, None, n_r)]
        if n_a:
            train.append(episodes("advisor episodes", advisor_act, adv_params, n_a, OU_SIGMA))
        held = {
            "random": episodes("held-out random", random_act, None, n_h),
            "advisor": episodes("held-out advisor", advisor_act, adv_params, n_h, OU_SIGMA),
        }
        norm = normalizer_from_data(flat(train[:1]), int(train[0]["valid"].sum()))
        fitted, losses = {}, {}
        for name, hidden in models.items():
            model = make_dynamics_model(hidden)
            state = model.init(next(keys)).replace(norm=norm)
            fitted[name] = refit(f"fit {name} {hidden}", model, state, flat(train))
            losses[name] = [fitted[name][2][-1]]
        policy = make_mpc_policy(fitted["main"][0], args.candidates, args.horizon, env.config)

        for r in range(args.rounds):  # on-policy aggregation, driven by the main model
            state = fitted["main"][1]
            label = f"round {r + 1}: MPC episodes"
            train.append(episodes(label, mpc_act, (state.params, state.norm), args.round_episodes))
            for name in models:
                model, state, _ = fitted[name]
                fitted[name] = refit(f"round {r + 1}: refit {name}", model, state, flat(train))
                losses[name].append(fitted[name][2][-1])

        eval_key, state = next(keys), fitted["main"][1]
        label = f"MPC evaluation (K {args.candidates}, H {args.horizon})"
        params = (state.params, state.norm)
        mpc = episodes(label, mpc_act, params, args.mpc_episodes, reset_key=eval_key)
        task = progress.add_task("advisor evaluation", total=1)
        evaluate = make_evaluate(env, lambda p, o: advisor_action(o, p), args.mpc_episodes)
        advisor_metrics = jax.jit(evaluate)(adv_params, eval_key)  # same starts and goals
        progress.update(task, completed=1)
        held["mpc"] = {f: (v if f == "metrics" else v[:, :n_h]) for f, v in mpc.items()}

        task = progress.add_task("k-step errors", total=len(models) * len(held))
        errors = {name: {} for name in models}
        for name, (model, state, _) in fitted.items():
            for source, traj in held.items():
                errors[name][source] = kstep_errors(
                    model, state.params, state.norm, traj, args.horizons
                )
                progress.advance(task)

    a_goal = np.asarray(advisor_metrics.outcome) == envs.GOAL
    m_goal = np.asarray(mpc["metrics"].outcome) == envs.GOAL
    transitions = [int(t["valid"].sum()) for t in train]
    result = {
        **measure.provenance(),
        "command": writing.command_line(
            "experiments/mcp_model_quality.py", writing.changed_options(parser, args)
        ),
        "settings": vars(args) | {"h_max": env.max_episode_steps},
        "data": {
            "random": {"episodes": n_r, "transitions": transitions[0]},
            "advisor": {"episodes": n_a, "transitions": transitions[1] if n_a else 0},
            "mpc_rounds": {
                "episodes": args.rounds * args.round_episodes,
                "transitions": sum(transitions[1 + bool(n_a) :]),
            },
        },
        "models": {
            name: {"hidden": list(hidden), "final_loss_per_fit": losses[name]}
            for name, hidden in models.items()
        },
        "errors": errors,
        "mpc": summary(mpc["metrics"]),
        "advisor": summary(advisor_metrics),
        "paired": {
            "both": int(np.sum(a_goal & m_goal)),
            "mpc_only": int(np.sum(~a_goal & m_goal)),
            "advisor_only": int(np.sum(a_goal & ~m_goal)),
            "neither": int(np.sum(~a_goal & ~m_goal)),
        },
        "seconds": round(time.perf_counter() - t_start, 1),
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out.with_suffix(".json"), result)
    writing.write_markdown(out.with_suffix(".md"), report(result, list(held)), echo=True)
    return result


def _num(x, fmt=".3f") -> str:
    return "–" if x is None else format(x, fmt)


def report(r: dict, sources: list[str]) -> list[str]:
    s = r["settings"]
    pct = lambda x: f"{100 * x:.1f} %"  # noqa: E731
    speed = lambda x: "n/a" if x is None else f"{x:.2f} m/s"  # noqa: E731
    d = r["data"]
    lines = [
        "# MCP + model-free: dynamics model quality and the MPC controller",
        "",
        f"- command: `{r['command']}`",
        f"- machine: {r['host']}, {r['cpu_count']} CPUs, {r['device']} ({r['backend']}); "
        f"jax {r['jax']}; date {r['date']}; {r['seconds']} s",
        f"- arena `{s['arena']}`, h_max {s['h_max']}; docs/baselines.md, issue 19",
        f"- fit data: {d['random']['episodes']} random episodes ({d['random']['transitions']} "
        f"transitions), {d['advisor']['episodes']} advisor + OU episodes "
        f"({d['advisor']['transitions']}), {d['mpc_rounds']['episodes']} MPC episodes in "
        f"{s['rounds']} aggregation round(s) ({d['mpc_rounds']['transitions']}); normaliser from "
        f"the random episodes; {s['model_steps']} Adam steps per fit, batch {s['batch']}, "
        f"lr {s['model_lr']:g}, input noise {s['model_noise']:g}",
        f"- held-out: {s['heldout_episodes']} episodes each of random, advisor + OU, and the "
        "MPC's own evaluation episodes (fresh keys); every window inside an episode counts",
        "",
        "## Open-loop prediction error of the observation",
        "",
        "P RMSE (m) over the 16 readings, mean |error| of δ (rad, wrapped) and d (m), v RMSE "
        "(m/s); `model` is ŝ_{t+k} from s_t and the real actions, `zero` the zero-change "
        "predictor ŝ_{t+k} = s_t.",
    ]
    for name, m in r["models"].items():
        losses = ", ".join(f"{x:.4f}" for x in m["final_loss_per_fit"])
        lines += [
            "",
            f"### {name} model, hidden {tuple(m['hidden'])} (final fit losses: {losses})",
            "",
        ]
        rows = []
        for source in sources:
            for k, e in r["errors"][name][source].items():
                mo, ze = e["model"], e["zero_change"]
                rows.append(
                    (
                        source,
                        k,
                        e["windows"],
                        *(
                            f"{_num(mo[g])} / {_num(ze[g])}"
                            for g in ("P_rmse", "delta_mae", "d_mae", "v_rmse")
                        ),
                    )
                )
        lines += writing.markdown_table(
            (
                "held-out",
                "k",
                "windows",
                "P model / zero",
                "δ model / zero",
                "d model / zero",
                "v model / zero",
            ),
            rows,
            align="lrr",
        )
    p = r["paired"]
    lines += [
        "",
        f"## MPC (K {s['candidates']}, H {s['horizon']}) vs the advisor, "
        f"{s['mpc_episodes']} episodes, same starts and goals",
        "",
        *writing.markdown_table(
            ("controller", "success", "collision", "timeout", "collision speed", "mean length"),
            [
                (
                    name,
                    pct(x["success_rate"]),
                    pct(x["collision_rate"]),
                    pct(x["timeout_rate"]),
                    speed(x["mean_collision_speed"]),
                    f"{x['mean_length']:.1f}",
                )
                for name, x in (("MPC (main model)", r["mpc"]), ("advisor", r["advisor"]))
            ],
        ),
        "",
        f"Paired: both reach the goal in {p['both']} episodes, only the MPC in {p['mpc_only']}, "
        f"only the advisor in {p['advisor_only']}, neither in {p['neither']}. The MPC cannot see "
        "footprint collisions between sensor rays (envs/reward.py).",
    ]
    return lines


if __name__ == "__main__":
    main()

"""``benchmarks/campaign.py profile``: where an experiment's device time goes, op by op."""

import json
import os
from types import SimpleNamespace

import jax

import campaign  # benchmarks/ is on the tests' path (conftest.py)
import common
import profile_trace


def _event(name, start_us, duration_us, **stats):
    return SimpleNamespace(name=name, start_ns=start_us * 1000, duration_ns=duration_us * 1000, stats=list(stats.items()))


def _profile(*planes):
    return SimpleNamespace(planes=[SimpleNamespace(name=name, lines=[SimpleNamespace(name=line, events=events)
                                                                     for line, events in lines.items()])
                                   for name, lines in planes])


ANNOTATIONS = ("/host:CPU", {"python": [_event("campaign:chunk", 0, 100), _event("campaign:scoring", 100, 200)]})


def _summaries(profile, steps=(5, 4)):
    where, ops = profile_trace.device_ops(profile)
    return where, [profile_trace.summarize_part(ops, part, profile_trace.annotation(profile, part), count, top=5)
                   for part, count in zip((campaign.CHUNK_PART, campaign.SCORING_PART), steps)]


def test_a_gpu_trace_is_summed_per_part_from_its_stream_lines():
    """Busy time is the union of the streams' kernels and copies (overlaps once), clipped to
    each part; kinds are HLO ops without their numbering, else the kernel's name; a derived
    line spanning the whole trace is not a stream, so it counts neither as busy nor as an op."""
    gpu = ("/device:GPU:0", {
        "Stream #1(Kernel)": [_event("loop_fusion_kernel", 10, 20, hlo_op="fusion.1"),
                              _event("loop_fusion_kernel", 40, 10, hlo_op="fusion.2"),
                              _event("smooth_kernel_forward", 150, 100), _event("fusion_kernel", 290, 30, hlo_op="fusion.7")],
        "Stream #2(MemcpyD2H)": [_event("MemcpyD2H", 20, 15)],
        "XLA Ops": [_event("fusion.1", 0, 300)],
    })
    where, (chunk, scoring) = _summaries(_profile(ANNOTATIONS, gpu))
    assert where == "/device:GPU:0"
    assert (chunk["wall_ms"], chunk["busy_ms"], chunk["ops"], chunk["steps"]) == (0.1, 0.035, 3, 5)
    assert (chunk["busy_us_per_step"], chunk["idle_us_per_step"], chunk["ops_per_step"]) == (7.0, 13.0, 0.6)
    assert [(row["op"], row["ms"], row["count"]) for row in chunk["costliest"]] == [("fusion", 0.03, 2), ("MemcpyD2H", 0.015, 1)]
    # The scoring part ends at 300 µs: the kernel running past it counts 10 of its 30 µs.
    assert (scoring["busy_ms"], scoring["ops"], scoring["busy_share"]) == (0.11, 2, 0.55)
    assert [row["op"] for row in scoring["costliest"]] == ["smooth_kernel_forward", "fusion"]
    assert "campaign:scoring: wall 0.2 ms, device busy 0.1 ms (55%); 2 ops = 0.5 per step" in profile_trace.describe(scoring)


def test_ops_are_counted_under_the_longest_scope_of_ours_their_name_stack_starts_with():
    """An op's source is read from its HLO metadata, through JAX's transformations and past
    Flax's and MJX's own scopes; an op XLA added counts as its computation's most common
    source (none where nothing there names one), and kernels naming no HLO op are another
    library's."""
    hlo = "\n".join([
        '  %fusion.3 = f32[8]{0} fusion(%p), kind=kLoop, metadata={op_name="jit(run_piece)/while/body/closed_call/'
        'learn/vmap()/updates/transpose(jvp(Actor))/Dense_0/dot_general"}',
        '  %fusion.4 = f32[8]{0} fusion(%p), metadata={op_name="jit(run_piece)/while/body/learn/minibatches/gather"}',
        '  ROOT %select.1 = f32[8]{0} select(%a, %b, %c), metadata={op_name="jit(run_piece)/while/body/closed_call/'
        'vmap()/env_step/forward/solve/while/body/select_n"}',
        '  %add.2 = f32[] add(%x, %y), metadata={op_name="jit(run_piece)/while/body/closed_call/add"}',
        '  %add.4 = f32[] add(%x, %y), metadata={op_name="jit(spread_call)/vmap(jit(_scores))/while/body/'
        'vmap(score_env_step)/vmap()/reshape"}',
        '  %copy.5 = f32[8]{0} copy(%p)',
        '}',
        '',
        '%region_7.2 (p: f32[8]) -> f32[8] {',
        '  %reduce-window.1 = f32[8,1]{1,0} reduce-window(%a, %b), window={size=32x1}, to_apply=%region_9',
        '  %copy.6 = f32[8]{0} copy(%reduce-window.1)',
        '  %select.2 = f32[8]{0} select(%a, %b, %c), metadata={op_name="jit(run_piece)/env_step/forward/select_n"}',
        '  %select.3 = f32[8]{0} select(%a, %b, %c), metadata={op_name="jit(run_piece)/env_step/forward/select_n"}',
        '  ROOT %add.3 = f32[8]{0} add(%a, %b), metadata={op_name="jit(run_piece)/while/body/learn/add"}',
        '}',
        '',
        '%region_8.3 (p: f32[8]) -> f32[8] {',
        '  ROOT %copy.7 = f32[8]{0} copy(%p)',
    ])
    sources = profile_trace.op_sources(hlo)
    # A scope entered under jax.vmap reads vmap(score_env_step). In the second computation the
    # ops XLA added count as its most common source, env_step.
    assert sources == {"fusion.3": "learn/updates", "fusion.4": "learn/minibatches", "select.1": "env_step",
                       "add.2": profile_trace.UNSCOPED, "add.4": "score_env_step", "copy.5": "learn/updates", "reduce-window.1": "env_step",
                       "copy.6": "env_step", "select.2": "env_step", "select.3": "env_step", "add.3": "learn",
                       "copy.7": profile_trace.NO_SOURCE}
    ops = [profile_trace.Op("t", "fusion", 0, 4, "fusion.3"), profile_trace.Op("t", "copy", 4, 5, "copy.7"),
           profile_trace.Op("t", "smooth_kernel", 5, 8), profile_trace.Op("t", "fusion", 8, 10, "fusion.3")]
    part = profile_trace.summarize_part(ops, "chunk", (0, 10), 2, top=3, sources=sources)
    assert [(row["source"], row["ms"], row["ops_per_step"]) for row in part["by_source"]] == [
        ("learn/updates", 0.006, 1.0), (profile_trace.NOT_LAUNCHED_BY_XLA, 0.003, 0.5), (profile_trace.NO_SOURCE, 0.001, 0.5)]
    # Each source names the op kinds it runs most, per step.
    assert [row["most_run"] for row in part["by_source"]] == [
        [{"op": "fusion", "per_step": 1.0}], [{"op": "smooth_kernel", "per_step": 0.5}], [{"op": "copy", "per_step": 0.5}]]
    assert "1.0 fusion" in profile_trace.describe(part)
    # Programs compiled by code without our scopes (a stale compilation cache) are told apart.
    stale = profile_trace.summarize_part(ops, "chunk", (0, 10), 2, top=3, sources={"fusion.3": profile_trace.UNSCOPED})
    assert profile_trace.names_our_scopes([part]) and not profile_trace.names_our_scopes([stale])


def test_xla_cpu_thunks_count_once_and_runtime_events_not_at_all():
    """On XLA:CPU a while thunk spans the thunks it runs and the executor's own events name no
    HLO op: only the leaves count. A trace with neither device planes nor thunks says so."""
    cpu = ("/host:CPU", {
        "python": ANNOTATIONS[1]["python"],
        "tf_XLAEigen/1": [_event("ThunkExecutor::Execute", 0, 60), _event("while.3", 2, 48, hlo_op="while.3"),
                          _event("copy.1", 5, 5, hlo_op="copy.1"), _event("add.2", 20, 10, hlo_op="add.2")],
    })
    where, (chunk, _) = _summaries(_profile(cpu))
    assert where == "XLA:CPU worker threads"
    assert sorted((row["op"], row["ms"]) for row in chunk["costliest"]) == [("add", 0.01), ("copy", 0.005)]
    # A GPU traced without CUPTI has no device planes, nor XLA:CPU thunks: said, not summed as idle.
    assert profile_trace.device_ops(_profile(ANNOTATIONS))[0].startswith("no device ops in the trace")


def test_profile_of_an_experiment_records_both_parts(tmp_path, monkeypatch, capsys):
    """The experiment's own programs, a training chunk that learns throughout and a scoring
    round at full length, traced and summed into one record (point mass, JAX physics)."""
    monkeypatch.setattr(common, "RESULTS_DIR", str(tmp_path))
    # Compiled afresh: a program from the persistent cache keeps the names of the code that
    # compiled it (metadata is not part of the cache key), so an older cache could hide a scope.
    cached = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    try:
        status = campaign.main(["profile", "env=point_mass", "physics=jax", "seeds=1", "modes=adversarial,uniform",
                                "score_every=40", "num_envs=4", "learning_starts=48", "batch_size=32", "hidden_size=32",
                                "buffer_size=1000", "score_episodes=2", "episode_length=10", "top=4"])
    finally:
        jax.config.update("jax_enable_compilation_cache", cached)
    assert status == 0
    with open(os.path.join(tmp_path, "campaign_profile.jsonl")) as file:
        (record,) = [json.loads(line) for line in file]
    assert (record["pairs"], record["chunk_learned_share"], record["ops_from"]) == (2, 1.0, "XLA:CPU worker threads")
    chunk, scoring = record["parts"]
    assert (chunk["part"], chunk["steps"], scoring["part"], scoring["steps"]) == (
        campaign.CHUNK_PART, 10, campaign.SCORING_PART, 10)  # 40 env steps of 4 envs; episodes of 10 steps
    for part in (chunk, scoring):
        assert part["ops"] > 0 and 0 < part["busy_ms"] <= part["wall_ms"] and len(part["costliest"]) == 4
    # Every scope the two programs name is found.
    assert {"act", "env_step", "replay_insert", "episode_starts", "learn/minibatches", "learn/updates"} <= {
        row["source"] for row in chunk["by_source"]}
    assert {"score_policy", "score_env_step"} <= {row["source"] for row in scoring["by_source"]}
    out = capsys.readouterr().out
    assert f"{campaign.CHUNK_PART}: wall {chunk['wall_ms']:,.1f} ms" in out and "warning" not in out

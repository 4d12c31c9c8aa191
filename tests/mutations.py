"""Break the method on purpose, one place at a time, and check that a test fails.

    python tests/mutations.py                  # every mutation below (about an hour on 2 cores, warm caches)
    python tests/mutations.py tau_doubled ...  # these only

A test earns its place by failing when the behaviour it names is broken. Each mutation below
is a small, plausible bug in the paper's method, the SAC update, scoring, the envs, the
statistics the figures report, what keeps a run's finished work (checkpoints, resume,
fast-forward, the records) or what reports on it (wrappers, audit, video). For each, this
script copies the working tree (tracked and untracked files, as git lists them) to a
temporary folder, writes the bug there (the working tree is never touched), and runs the
tests: first the file named beside the mutation, where it was caught before, then, if that
file passes, the whole suite. It prints one JSON line per mutation (with what the catching
test said: a test failing for another reason than the bug shows there) and exits 1 if any
survives, naming it. Only a failed test is a catch: pytest stopping without one (a
collection error, a crash: a broken mutation or environment) counts as a survivor, with
pytest's reason. Record of the last pass: ``tests/data/mutations.jsonl``.

Not part of the test command (pytest collects ``test_*.py`` only): each mutation recompiles
what it touches, minutes where the suite takes seconds per file.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# name: (file, text, its replacement, the test file that caught it last)
# envs/warp_package.py's MuJoCo Warp passes built in RUN_TO_RUN mode, which two mutations each cut by one.
_BOTH_PASSES = '_RUN_TO_RUN_PASSES = (("collision_driver", "collision"), ("constraint", "make_constraint"))'
MUTATIONS: dict[str, tuple[str, str, str, str]] = {
    # The paper's mechanism (§3): u per episode, masking, the adversary's p_miss.
    "u_redrawn_every_step": ("admissable_jax/training.py", "set_index=jnp.where(done, new_sets, state.set_index)",
                             "set_index=new_sets", "test_mechanism.py"),
    "stored_with_set_zero": ("admissable_jax/training.py", "set_index=state.set_index,\n",
                             "set_index=jnp.zeros_like(state.set_index),\n", "test_mechanism.py"),
    "mode_none_masks": ("admissable_jax/training.py",
                        "return self.sets.rows(set_index) * state.masking.astype(jnp.float32)",
                        "return self.sets.rows(set_index)", "test_mechanism.py"),
    "next_obs_unmasked": ("admissable_jax/training.py", "next_obs=mask_observation(batch.next_obs, hidden),",
                          "next_obs=mask_observation(batch.next_obs, 0 * hidden),", "test_mechanism.py"),
    "next_obs_is_obs": ("admissable_jax/training.py", "next_obs=stepped.obs,", "next_obs=state.env_states.obs,",
                        "test_mechanism.py"),
    "uniform_mode_draws_from_pool": ("admissable_jax/training.py", "jnp.where(adversarial, self.spec.pool_explore, 1.0)",
                                     "jnp.where(adversarial, self.spec.pool_explore, 0.0)", "test_training.py"),
    "uniform_mode_updates_p_miss": ("admissable_jax/adversary.py",
                                    "jnp.where(adversarial, inverse_score_p_miss(scores, lower_bound, epsilon), p_miss)",
                                    "inverse_score_p_miss(scores, lower_bound, epsilon)", "test_missingness.py"),
    "uniform_runs_as_adversarial": ("admissable_jax/host_loop.py",
                                    'return config.seed, mode == "adversarial", mode != "none", config.lower_bound',
                                    'return config.seed, mode != "none", mode != "none", config.lower_bound',
                                    "test_hopper_pipelines.py"),
    "scores_below_l_not_clipped": ("admissable_jax/method.py", "xp.maximum(scores - lower_bound, 0.0) + epsilon",
                                   "xp.abs(scores - lower_bound) + epsilon", "test_missingness.py"),
    "p_miss_proportional_not_inverse": ("admissable_jax/method.py",
                                        "weights = 1.0 / (xp.maximum(scores - lower_bound, 0.0) + epsilon)",
                                        "weights = (xp.maximum(scores - lower_bound, 0.0) + epsilon)",
                                        "test_missingness.py"),
    "hidden_features_not_zeroed": ("admissable_jax/method.py", "xp.concat([obs * (1 - hidden), hidden], axis=-1)",
                                   "xp.concat([obs, hidden], axis=-1)", "test_missingness.py"),
    "indicator_inverted": ("admissable_jax/method.py", "xp.concat([obs * (1 - hidden), hidden], axis=-1)",
                           "xp.concat([obs * (1 - hidden), 1 - hidden], axis=-1)", "test_missingness.py"),
    "wrapper_uniform_updates_p_miss": ("admissable_jax/wrappers.py", 'if self.mode == "adversarial":\n            self.p_miss',
                                       'if True:\n            self.p_miss', "test_wrappers.py"),
    "wrapper_draws_uniformly": ("admissable_jax/wrappers.py", "int(rng.choice(len(self.p_miss), p=self.p_miss))",
                                "int(rng.choice(len(self.p_miss)))", "test_wrappers.py"),
    "draws_ignore_p_miss": ("admissable_jax/training.py", "return sample_set_indices(rng, p_miss, shape)",
                            "return sample_set_indices(rng, jnp.ones_like(p_miss) / p_miss.shape[0], shape)",
                            "test_mechanism.py"),
    "lower_bound_ignored": ("admissable_jax/training.py", "state.adversarial, state.lower_bound, self.spec.epsilon",
                            "state.adversarial, 0.0, self.spec.epsilon", "test_experiment.py"),
    "pool_never_explores": ("admissable_jax/training.py", "jnp.where(adversarial, self.spec.pool_explore, 1.0)",
                            "jnp.where(adversarial, 0.0, 1.0)", "test_training.py"),
    "experiment_seeds_all_first": ("admissable_jax/config.py", "missingness=mode, seed=seed,",
                                   "missingness=mode, seed=config.first_seed,", "test_experiment.py"),
    "scoring_policy_stochastic": ("admissable_jax/training.py",
                                  "return self.agent.deterministic_action(actor_params, masked_obs)",
                                  "return self.agent.sample_action(actor_params, masked_obs, jax.random.key(0))[0]",
                                  "test_training.py"),
    # Training's schedule and SAC (SB3's semantics).
    "learning_starts_one_early": ("admissable_jax/training.py", "return state.env_steps > self.spec.learning_starts",
                                  "return state.env_steps >= self.spec.learning_starts", "test_hopper_pipelines.py"),
    "random_actions_one_late": ("admissable_jax/training.py", "jnp.where(state.env_steps < self.spec.learning_starts",
                                "jnp.where(state.env_steps <= self.spec.learning_starts", "test_mechanism.py"),
    "interval_one_iteration_long": ("admissable_jax/run_spec.py",
                                    "iterations_per_scoring=config.score_every // config.num_envs,",
                                    "iterations_per_scoring=config.score_every // config.num_envs + 1,",
                                    "test_hopper_pipelines.py"),
    "episodes_restart_only_on_termination": ("admissable_jax/envs/state.py", "jnp.where(state.done, new, old)",
                                             "jnp.where(state.terminated, new, old)", "test_mechanism.py"),
    "replay_samples_empty_rows": ("admissable_jax/replay.py", "0, jnp.maximum(buffer.size, 1))",
                                  "0, buffer.data.reward.shape[0])", "test_agent.py"),
    "bootstrap_through_termination": ("admissable_jax/sac_losses.py", "1.0 - terminated.astype(jnp.float32)",
                                      "1.0 + 0.0 * terminated.astype(jnp.float32)", "test_agent.py"),
    "no_entropy_in_target": ("admissable_jax/sac_losses.py", "(next_q - alpha * next_log_prob)",
                             "(next_q - 0.0 * alpha * next_log_prob)", "test_agent.py"),
    "alpha_loss_sign": ("admissable_jax/sac_losses.py", "return -jnp.mean(log_alpha * jax.lax.stop_gradient(",
                        "return jnp.mean(log_alpha * jax.lax.stop_gradient(", "test_agent.py"),
    "no_tanh_correction": ("admissable_jax/agent.py", "jnp.sum(gaussian_log_prob - log_det, axis=-1)",
                           "jnp.sum(gaussian_log_prob - 0 * log_det, axis=-1)", "test_agent.py"),
    "tau_doubled": ("admissable_jax/agent.py", "state.target_critic_params, hp.tau)",
                    "state.target_critic_params, 2 * hp.tau)", "test_agent.py"),
    "truncation_stored_as_termination": ("admissable_jax/training.py", "terminated=stepped.terminated,",
                                         "terminated=stepped.done,", "test_mechanism.py"),
    "target_entropy_halved": ("admissable_jax/agent.py", "self.target_entropy = -float(self.action_size)",
                              "self.target_entropy = -0.5 * float(self.action_size)", "test_agent.py"),
    # Scoring: a_u, its estimators, and what the records report.
    "scoring_start_states_differ_per_set": ("admissable_jax/scoring/rollout_scores.py",
                                            "return jax.tree.map(lambda x: x[episode % n_episodes], initial)",
                                            "return jax.tree.map(lambda x: x[(episode // n_episodes + episode) "
                                            "% n_episodes], initial)", "test_training.py"),
    "scoring_episodes_end_at_999": ("admissable_jax/scoring/rollout_scores.py", "(states.step_count >= max_steps)",
                                    "(states.step_count >= max_steps - 1)", "test_training.py"),
    "clean_case_hides_a_feature": ("admissable_jax/scoring/rollout_scores.py", "jnp.zeros((1, num_features))]",
                                   "jnp.eye(1, num_features)]", "test_mechanism.py"),
    "min_score_is_the_mean": ("admissable_jax/scoring/rollout_scores.py", "return jnp.min(self.scores)",
                              "return jnp.mean(self.scores)", "test_hopper_pipelines.py"),
    "estimate_bootstraps_max_twin": ("admissable_jax/scoring/value_estimates.py", "gamma**horizon * jnp.min(q, axis=-1)",
                                     "gamma**horizon * jnp.max(q, axis=-1)", "test_audit.py"),
    "estimate_undiscounted": ("admissable_jax/scoring/value_estimates.py",
                              "jnp.where(alive, gamma**t * states.reward, 0.0)", "jnp.where(alive, states.reward, 0.0)",
                              "test_audit.py"),
    "shapley_weights_unnormalised": ("admissable_jax/scoring/attribution.py",
                                     "math.factorial(d - s - 1) / math.factorial(d)",
                                     "math.factorial(d - s - 1) / math.factorial(d - 1)", "test_audit.py"),
    "beam_keeps_the_highest": ("admissable_jax/scoring/set_search.py", "order = jnp.argsort(scores, stable=True)[:b]",
                               "order = jnp.argsort(-scores, stable=True)[:b]", "test_audit.py"),
    "refill_skips_an_episode": ("admissable_jax/scoring/rollout_scores.py",
                                "next_episode = carry[\"next_episode\"] + jnp.cumsum(finished) - 1",
                                "next_episode = carry[\"next_episode\"] + jnp.cumsum(finished)", "test_training.py"),
    "refilled_slots_stop": ("admissable_jax/scoring/rollout_scores.py", '"alive": jnp.where(finished, refill, alive)',
                            '"alive": jnp.where(finished, False, alive)', "test_training.py"),
    "set_index_without_its_size_block": ("admissable_jax/method.py",
                                         "return xp.take(xp.asarray(first_of_size), size) + rank", "return rank",
                                         "test_missingness.py"),
    # The paper's settings and SB3's as the defaults a user gets.
    "default_n_5": ("admissable_jax/config.py", 'setting(10, "N: deterministic', 'setting(5, "N: deterministic',
                    "test_training.py"),
    "default_zeta_2000": ("admissable_jax/config.py", 'setting(5000, "zeta', 'setting(2000, "zeta', "test_training.py"),
    "default_epsilon_1e-3": ("admissable_jax/config.py", 'setting(1e-8, "eps', 'setting(1e-3, "eps', "test_training.py"),
    "default_tau_doubled": ("admissable_jax/agent.py", "tau: float = 0.005", "tau: float = 0.01", "test_training.py"),
    "default_batch_128": ("admissable_jax/agent.py", "batch_size: int = 256", "batch_size: int = 128", "test_training.py"),
    # The envs' v5 semantics (Gymnasium's *_v5.py).
    "hopper_angle_range_wider": ("admissable_jax/envs/planar_walkers.py", "healthy_angle_range = (-0.2, 0.2)",
                                 "healthy_angle_range = (-0.25, 0.25)", "test_envs.py"),
    "walker2d_z_range_higher": ("admissable_jax/envs/planar_walkers.py", "healthy_z_range = (0.8, 2.0)",
                                "healthy_z_range = (0.8, 2.5)", "test_envs.py"),
    "ant_contact_cost_doubled": ("admissable_jax/envs/ant.py", "_CONTACT_COST_WEIGHT = 5e-4",
                                 "_CONTACT_COST_WEIGHT = 1e-3", "test_envs.py"),
    # Records, resume, fast-forward and the audit's report: finished work kept and told right.
    "no_checkpoint_at_a_pause": ("admissable_jax/host_loop.py",
                                 "== 0 or last or pause or stopped", "== 0 or last or stopped", "test_runs.py"),
    "no_checkpoint_at_the_end": ("admissable_jax/host_loop.py",
                                 "== 0 or last or pause or stopped", "== 0 or pause or stopped", "test_training.py"),
    "checkpoint_every_one_early": ("admissable_jax/host_loop.py", "saving = (scoring + 1) % config.checkpoint_every",
                                   "saving = scoring % config.checkpoint_every", "test_training.py"),
    "time_limit_ignores_the_next_interval": ("admissable_jax/host_loop.py",
                                             "now - started_run + (now - interval_started) > config.time_limit",
                                             "now - started_run > config.time_limit", "test_runs.py"),
    "resume_keeps_rows_after_the_checkpoint": ("admissable_jax/host_loop.py",
                                               "run.set_aside_rows_after(records_kept_to)",
                                               "run.set_aside_rows_after(records_kept_to + config.planned_steps)",
                                               "test_runs.py"),
    "rows_at_the_checkpoint_set_aside": ("admissable_jax/run_directory.py",
                                         'later = [row for row in rows if row["env_steps"] > step]',
                                         'later = [row for row in rows if row["env_steps"] >= step]', "test_runs.py"),
    "divergence_seen_in_alpha_only": ("admissable_jax/host_loop.py", 'for name in ("critic_loss", "actor_loss", "alpha"):',
                                      'for name in ("alpha",):', "test_training.py"),
    "newer_checkpoints_kept_in_place": ("admissable_jax/checkpointing.py",
                                        "newer = [later for later in self._manager.all_steps() if later > step]",
                                        "newer = []", "test_runs.py"),
    "fast_forward_fingerprint_unchecked": ("admissable_jax/fast_forward.py", "if rebuilt != recorded.fingerprint:",
                                           "if False:", "test_training.py"),
    "fast_forward_ignores_recorded_p_miss": ("admissable_jax/host_loop.py",
                                             "state = trainer.after_scoring(state, p_miss, pool)",
                                             "state = trainer.after_scoring(state, state.p_miss, pool)",
                                             "test_training.py"),
    "argmin_set_is_the_first": ("admissable_jax/run_directory.py",
                                '"argmin_set": describe_set(np.asarray(hidden_sets[argmin])),',
                                '"argmin_set": describe_set(np.asarray(hidden_sets[0])),', "test_training.py"),
    "losses_averaged_over_warm_up": ("admissable_jax/run_directory.py",
                                     "row[name] = float(chunk[name][learned].mean()) if learned.any() else None",
                                     "row[name] = float(chunk[name].mean()) if learned.any() else None",
                                     "test_training.py"),
    "wrapper_counts_the_autoreset_step": ("admissable_jax/wrappers.py",
                                          "counted = ~resetting & (episode_of_slot < total)",
                                          "counted = episode_of_slot < total", "test_wrappers.py"),
    "wrapper_returns_carry_over": ("admissable_jax/wrappers.py",
                                   "running_return[ended], running_length[ended] = 0.0, 0",
                                   "running_length[ended] = 0", "test_wrappers.py"),
    "audit_worst_is_the_best": ("admissable_jax/audit/report.py",
                                "lambda result, k: min(entry.score for entry in result.sets[k])",
                                "lambda result, k: max(entry.score for entry in result.sets[k])", "test_experiment.py"),
    "audit_difference_reversed": ("admissable_jax/audit/report.py",
                                  'per_mode[curve][k],\n                                                        per_mode["uniform"][k])',
                                  'per_mode["uniform"][k],\n                                                        per_mode[curve][k])',
                                  "test_experiment.py"),
    "shapley_order_smallest_first": ("admissable_jax/audit/report.py",
                                     "key=lambda i: -attribution.values[i])",
                                     "key=lambda i: attribution.values[i])", "test_audit.py"),
    "video_hidden_side_sees_everything": ("admissable_jax/video.py",
                                          "action = policy(observations[side], hidden=sides[side])",
                                          "action = policy(observations[side], hidden=())", "test_hopper_pipelines.py"),
    "video_sides_start_apart": ("admissable_jax/video.py", "observations = [env.reset(seed=config.seed)[0] for env in envs]",
                                "observations = [env.reset(seed=config.seed + side)[0] for side, env in enumerate(envs)]",
                                "test_hopper_pipelines.py"),
    "rollout_never_resets": ("admissable_jax/rollout.py",
                             "return (jax.vmap(reset_where_done, (None, 0, 0))(env, states, reset_keys), total_reward), None",
                             "return (states, total_reward), None", "test_runs.py"),
    "pool_explore_unchecked": ("admissable_jax/config.py", "if not 0 <= config.pool_explore <= 1:", "if False:",
                               "test_training.py"),
    "audit_episodes_unchecked": ("admissable_jax/audit/command.py", "if config.episodes < 2:", "if False:",
                                 "test_audit.py"),
    # The statistics of the figures and FIGURE1.md.
    "interval_normal_not_t": ("admissable_jax/results.py", "stats.t.ppf(0.5 + confidence / 2, n - 1)",
                              "stats.norm.ppf(0.5 + confidence / 2)", "test_plots.py"),
    "interval_population_std": ("admissable_jax/results.py", "curves.std(axis=0, ddof=1)",
                                "curves.std(axis=0, ddof=0)", "test_plots.py"),
    "students_t_not_welchs": ("admissable_jax/results.py", "equal_var=False)", "equal_var=True)", "test_plots.py"),
    "auc_is_the_final_value": ("admissable_jax/results.py", "{estimate(minimum.mean(axis=1))}",
                               "{estimate(minimum[:, -1])}", "test_plots.py"),
    "moving_average_window_plus_one": ("admissable_jax/results.py",
                                       "np.minimum(np.arange(1, values.shape[-1] + 1), window)",
                                       "np.minimum(np.arange(1, values.shape[-1] + 1), window + 1)", "test_plots.py"),
    # Modules no mutation had touched before: u's draws, the replay ring, fingerprints, the memory
    # budget, the run lock, load_policy, the audit's statistics, placement, branching, loggers,
    # the estimators' dispatch, more v5 env constants, exit statuses, an experiment's resume.
    "distinct_sets_repeat": ("admissable_jax/missingness.py",
                             "jnp.where(jnp.any(chosen == candidate), last, candidate)", "candidate", "test_missingness.py"),
    "distinct_sets_never_draw_the_last": ("admissable_jax/missingness.py",
                                          "jax.random.randint(keys[i], (), 0, last + 1, jnp.int32)",
                                          "jax.random.randint(keys[i], (), 0, last, jnp.int32)", "test_missingness.py"),
    "replay_never_wraps": ("admissable_jax/replay.py", "position=(buffer.position + n) % capacity,",
                           "position=jnp.minimum(buffer.position + n, capacity - n),", "test_agent.py"),
    "fingerprint_blind_to_order": ("admissable_jax/fingerprints.py",
                                   "jnp.sum(words * (position * jnp.uint32(2) + jnp.uint32(1)) * jnp.uint32(_GOLDEN)",
                                   "jnp.sum(words * jnp.uint32(_GOLDEN)", "test_training.py"),
    "memory_budget_without_the_state": ("admissable_jax/memory.py",
                                        "return self.devices_sharing * (self.state_bytes + max(",
                                        "return self.devices_sharing * (0 + max(", "test_experiment.py"),
    "memory_state_not_split_over_devices": ("admissable_jax/memory.py", "MemoryBudget(total_state_bytes // num_devices,",
                                            "MemoryBudget(total_state_bytes,", "test_experiment.py"),
    "lock_of_another_host_taken_over": ("admissable_jax/locks.py",
                                        'if holder.get("host") != this_host:\n        return True',
                                        'if holder.get("host") != this_host:\n        return False', "test_runs.py"),
    "load_policy_takes_the_first_pair": ("admissable_jax/policies.py", "pick = lambda tree: take_pair(tree, index)",
                                         "pick = lambda tree: take_pair(tree, 0)", "test_experiment.py"),
    "gap_never_paired": ("admissable_jax/scoring/worst_set.py", "    if paired:\n        return gap, t_half_width(high - low)",
                         "    if False:\n        return gap, t_half_width(high - low)", "test_audit.py"),
    "episodes_to_separate_one_sided": ("admissable_jax/scoring/worst_set.py",
                                       "return (stats.t.ppf(0.975, freedom) + stats.t.ppf(0.8, freedom)) ** 2 * ratio",
                                       "return (stats.t.ppf(0.95, freedom) + stats.t.ppf(0.8, freedom)) ** 2 * ratio",
                                       "test_audit.py"),
    "audit_interval_normal_not_t": ("admissable_jax/scoring/worst_set.py",
                                    "width = stats.t.ppf(0.975, n - 1) * samples.std(axis=axis, ddof=1)",
                                    "width = 1.96 * samples.std(axis=axis, ddof=1)", "test_audit.py"),
    "padding_copies_the_first_pair": ("admissable_jax/placement.py",
                                      "np.repeat(values[-1:], self.padded_pairs - self.num_pairs, axis=0)",
                                      "np.repeat(values[:1], self.padded_pairs - self.num_pairs, axis=0)",
                                      "test_sharding.py"),
    "lazy_cond_takes_the_branch_for_all": ("admissable_jax/branching.py",
                                           "jnp.where(per_member(t), t, s), taken, skipped)",
                                           "t, taken, skipped)", "test_training.py"),
    "while_any_stops_with_the_first": ("admissable_jax/branching.py",
                                       "lambda carry, *operands: jnp.any(cond_each(carry, *operands))",
                                       "lambda carry, *operands: jnp.all(cond_each(carry, *operands))",
                                       "test_training.py"),
    "loggers_lose_the_env_step": ("admissable_jax/loggers.py", "return FlatRow(int(row[\"env_steps\"]), scalars, p_miss)",
                                  "return FlatRow(0, scalars, p_miss)", "test_runs.py"),
    "critic_estimate_rolls_out_h_steps": ("admissable_jax/scoring/estimators.py",
                                          'horizon = score_horizon if score_estimator == "horizon" else 0',
                                          "horizon = score_horizon", "test_audit.py"),
    "walker_qvel_clip_wider": ("admissable_jax/envs/planar_walkers.py", "_QVEL_CLIP = 10.0", "_QVEL_CLIP = 20.0",
                               "test_envs.py"),
    "halfcheetah_ctrl_cost_halved": ("admissable_jax/envs/half_cheetah.py", "_CTRL_COST_WEIGHT = 0.1",
                                     "_CTRL_COST_WEIGHT = 0.05", "test_envs.py"),
    "ant_healthy_z_strict": ("admissable_jax/envs/ant.py", "(low <= qpos[2]) & (qpos[2] <= high)",
                             "(low < qpos[2]) & (qpos[2] < high)", "test_envs.py"),
    "bad_settings_exit_1": ("admissable_jax/cli.py", "            return None, USAGE_ERROR\n",
                            "            return None, 1\n", "test_runs.py"),
    "experiment_resumes_other_pairs": ("admissable_jax/experiment.py", "    if saved != names(pairs):\n",
                                       "    if False:\n", "test_experiment.py"),
    # The env step's bookkeeping, SAC's twins and log-std clamp, which checkpoint resumes, the
    # audit's default sizes, the wrapper's space, the summary's worst u.
    "truncated_one_step_early": ("admissable_jax/envs/base.py", "truncated=step_count >= self.max_episode_steps,",
                                 "truncated=step_count >= self.max_episode_steps - 1,", "test_mechanism.py"),
    "terminate_when_unhealthy_ignored": ("admissable_jax/envs/base.py",
                                         "terminated=jnp.logical_not(healthy) & self.options.terminate_when_unhealthy,",
                                         "terminated=jnp.logical_not(healthy),", "test_envs.py"),
    "episode_return_forward_only": ("admissable_jax/envs/base.py",
                                    'episode_metrics["return"] = state.episode_metrics["return"] + reward',
                                    'episode_metrics["return"] = state.episode_metrics["return"] + terms[self.reward_terms[0]]',
                                    "test_training.py"),
    "target_from_the_larger_twin": ("admissable_jax/agent.py",
                                    "next_q = jnp.min(self.critic.apply(state.target_critic_params, batch.next_obs, next_action), axis=0)",
                                    "next_q = jnp.max(self.critic.apply(state.target_critic_params, batch.next_obs, next_action), axis=0)",
                                    "test_agent.py"),
    "actor_maximises_the_larger_twin": ("admissable_jax/agent.py",
                                        "q_pi = jnp.min(self.critic.apply(critic_params, batch.obs, action), axis=0)",
                                        "q_pi = jnp.max(self.critic.apply(critic_params, batch.obs, action), axis=0)",
                                        "test_agent.py"),
    "log_std_clamped_at_5": ("admissable_jax/agent.py", "LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0",
                             "LOG_STD_MIN, LOG_STD_MAX = -20.0, 5.0", "test_agent.py"),
    "resume_from_the_oldest_checkpoint": ("admissable_jax/checkpointing.py", "        if step is None:\n            return max(steps)",
                                          "        if step is None:\n            return min(steps)", "test_runs.py"),
    "audit_default_k_is_1": ("admissable_jax/audit/command.py",
                             "return tuple(set_sizes(train.k, train.up_to_k)) if train is not None else (1,)",
                             "return (1,)", "test_audit.py"),
    "wrapper_space_excludes_zero": ("admissable_jax/wrappers.py", "low=np.concatenate([np.minimum(space.low, 0), zeros]),",
                                    "low=np.concatenate([space.low, zeros]),", "test_wrappers.py"),
    "summary_worst_u_is_the_best": ("admissable_jax/results.py",
                                    "worst_sets = [names[i] for i in np.argmin(scores, axis=1)]",
                                    "worst_sets = [names[i] for i in np.argmax(scores, axis=1)]", "test_plots.py"),
    # The audit's Shapley values, the figures' adversarial − uniform, a sweep's pairs, the run's
    # summary and provenance, the spec's episode length and batch size.
    "shapley_orders_not_antithetic": ("admissable_jax/scoring/attribution.py",
                                      "order_table = np.stack([first, first[:, ::-1]], axis=1)",
                                      "order_table = np.stack([first, first], axis=1)", "test_audit.py"),
    "shapley_gains_by_position": ("admissable_jax/scoring/attribution.py",
                                  "contributions[np.arange(len(plan.orders))[:, None], plan.orders] = gains",
                                  "contributions[:] = gains", "test_audit.py"),
    "leave_one_out_reversed": ("admissable_jax/scoring/attribution.py",
                               "leave_one_out=(full.mean() - alone.mean(axis=1)).tolist()",
                               "leave_one_out=(alone.mean(axis=1) - full.mean()).tolist()", "test_audit.py"),
    "mode_differences_reversed": ("admissable_jax/results.py", "Difference(name, values[:n], values[n:])",
                                  "Difference(name, values[n:], values[:n])", "test_plots.py"),
    "sweep_trains_uniform_per_l": ("admissable_jax/config.py",
                                   'for bound in (swept if swept and mode == "adversarial" else [shared["lower_bound"]])]',
                                   'for bound in (swept if swept else [shared["lower_bound"]])]', "test_experiment.py"),
    "summary_clean_is_min_score": ("admissable_jax/train.py", "clean {last['clean_score']:.1f}; run in",
                                   "clean {last['min_score']:.1f}; run in", "test_experiment.py"),
    "provenance_never_marks_changes": ("admissable_jax/provenance.py",
                                       'return commit + ("+changes" if changed else "")', "return commit",
                                       "test_runs.py"),
    "run_spec_full_length_episodes": ("admissable_jax/run_spec.py", "episode_length=config.episode_length,",
                                      "episode_length=1000,", "test_training.py"),
    "max_batch_without_the_scoring_envs": ("admissable_jax/run_spec.py",
                                           "max(config.num_envs, config.score_envs, horizon_ranker_batch(config))",
                                           "max(config.num_envs, horizon_ranker_batch(config))",
                                           "test_hopper_pipelines.py"),
    "kernels_counted_in_the_first_call": ("benchmarks/device_pack.py",
                                          'packed_entry(FIRST_PART),\n'
                                          '            second_call_fixed=folder_bytes(os.path.join(dev, "b"), root) - packed_entry(REST)\n'
                                          '            + folder_bytes(os.path.join(dev, KERNELS), root),',
                                          'packed_entry(FIRST_PART)\n'
                                          '            + folder_bytes(os.path.join(dev, KERNELS), root),\n'
                                          '            second_call_fixed=folder_bytes(os.path.join(dev, "b"), root) - packed_entry(REST),',
                                          "test_device_pack.py"),
    "compacted_palette_of_16_colours": ("benchmarks/compact_pngs.py", "PALETTE_COLOURS = 256", "PALETTE_COLOURS = 16",
                                        "test_device_pack.py"),
    "compacting_rewrites_palette_pngs": ("benchmarks/compact_pngs.py", 'if image.mode == "P":', "if False:",
                                         "test_device_pack.py"),
    "figure1_drops_the_notes_by_hand": ("benchmarks/figure1.py", 'return text[start + 1:] if start >= 0 else ""',
                                        'return ""', "test_figure1.py"),
    "figure1_names_the_commit_after_drawing": ("benchmarks/figure1.py", 'at commit {commit}, from',
                                               "at commit {benchmark_commit()}, from", "test_figure1.py"),
    "figure1_counts_results_as_changes": ("benchmarks/common.py", 'source_commit(exclude=("benchmarks/results",))',
                                          "source_commit()", "test_figure1.py"),
    "continuation_scores_its_recorded_intervals": ("benchmarks/campaign.py",
                                                   '(scorings - retrained) * record["score_full_s"]',
                                                   'scorings * record["score_full_s"]', "test_campaign_plan.py"),
    "campaign_continues_records_without_fast_forward": ("benchmarks/gpu_campaign.sh",
                                                        "then resume=true; forward=true; fi", "then resume=true; fi",
                                                        "test_hopper_pipelines.py"),
    "campaign_ignores_first_seed": ("benchmarks/gpu_campaign.sh", "sizes+=(first_seed=${CAMPAIGN_FIRST_SEED:-0})",
                                    "sizes+=()", "test_hopper_pipelines.py"),
    "campaign_runs_only_the_planned_steps": ("benchmarks/gpu_campaign.sh", '"$modes" total_steps=$full_steps "${sizes[@]}"',
                                             '"$modes" total_steps=$planned "${sizes[@]}"', "test_hopper_pipelines.py"),
    "campaign_run_unbounded_by_the_deadline": ("benchmarks/gpu_campaign.sh",
                                               "'BEGIN { left = int(deadline - spent - reserve); print (left >= 1 ? left : 1) }')",
                                               "'BEGIN { print 0 }')", "test_hopper_pipelines.py"),
    "campaign_deadline_stop_resumed": ("benchmarks/gpu_campaign.sh", 'elif [ "$by_deadline" = true ]; then',
                                       "elif false; then", "test_hopper_pipelines.py"),
    "left_out_wheels_packed": ("benchmarks/device_pack.py", '    leave_out_wheels(os.path.join(dev, "a", "whl"))\n', "",
                               "test_device_pack.py"),
    "campaign_imports_a_left_out_module": ("admissable_jax/experiment.py", "from __future__ import annotations\n",
                                           "from __future__ import annotations\nimport glfw  # a viewer's, on the campaign's path\n",
                                           "test_hopper_pipelines.py"),
    # MuJoCo Warp's deterministic mode (envs/warp_package.py) and the check that a machine repeats a run.
    "warp_physics_not_deterministic": ("admissable_jax/envs/options.py", "    deterministic: bool = True\n",
                                       "    deterministic: bool = False\n", "test_envs.py"),
    "warp_mode_set_on_no_bridge": ("admissable_jax/envs/warp_package.py",
                                   'importlib.import_module(f"mujoco.mjx.warp.{name}")._o.deterministic = mode',
                                   "mode", "test_envs.py"),
    "collision_kernels_not_run_to_run": ("admissable_jax/envs/warp_package.py", _BOTH_PASSES,
                                         '_RUN_TO_RUN_PASSES = (("constraint", "make_constraint"),)', "test_envs.py"),
    "constraint_rows_not_run_to_run": ("admissable_jax/envs/warp_package.py", _BOTH_PASSES,
                                       '_RUN_TO_RUN_PASSES = (("collision_driver", "collision"),)', "test_envs.py"),
    "warp_atomics_counters_read_as_integers": ("benchmarks/warp_atomics.py", "            if result and re.search(",
                                               "            if False and re.search(", "test_warp_kernels.py"),
    "compile_time_floor_forced": ("admissable_jax/cli.py", '    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:',
                                  "    if True:", "test_repeatability.py"),
    "notebook_pngs_not_compacted": ("benchmarks/compact_pngs.py", 'png = smaller_png(base64.b64decode(data["image/png"]))',
                                    'png = base64.b64decode(data["image/png"])', "test_device_pack.py"),
    "campaign_determinism_cost_not_measured": ("benchmarks/gpu_campaign.sh", "for mode in true false; do",
                                               "for mode in true; do", "test_hopper_pipelines.py"),
    "kernel_archive_packs_what_another_holds": ("benchmarks/warp_kernels.py", "for path in files} - packed)",
                                                "for path in files})", "test_warp_kernels.py"),
    "campaign_runs_leave_the_mode_to_the_default": ("benchmarks/gpu_campaign.sh", "  sizes+=(deterministic_physics=true)\n", "",
                                                    "test_hopper_pipelines.py"),
    "mjx_own_warp_not_kept": ("admissable_jax/envs/warp_package.py", 'if os.environ.get(OWN_COPY_VARIABLE) == "1":',
                              'if os.environ.get(OWN_COPY_VARIABLE) == "yes":', "test_envs.py"),
    "mujoco_warp_release_not_checked": ("admissable_jax/envs/warp_package.py", "    if _package_refused:\n",
                                        "    if False:\n", "test_envs.py"),
    "device_pack_extra_wheel_not_pyprojects": ("benchmarks/device_pack.py", 'EXTRA_WHEELS = _cuda_extra_pins("mujoco-warp")',
                                               'EXTRA_WHEELS = ("mujoco-warp==4.0.0",)', "test_device_pack.py"),
    "campaign_repeatability_not_run": ("benchmarks/gpu_campaign.sh", "      stage repeatability-hopper 600 ",
                                       "      : stage repeatability-hopper 600 ", "test_hopper_pipelines.py"),
    "repeatability_rebuild_reuses_the_compiled_programs": ("benchmarks/repeatability.py", ", environment=fresh_cache)", ")",
                                                           "test_repeatability.py"),
    "warp_atomics_counts_adjoint_targets": ("benchmarks/warp_atomics.py",
                                            "sum(target.use_forward for target in meta.scatter_targets)",
                                            "len(meta.scatter_targets)", "test_warp_kernels.py"),
    "campaign_deterministic_buffers_not_checked": ("benchmarks/gpu_campaign.sh", "deterministic=true graph_modes=NONE",
                                                   "deterministic=true", "test_hopper_pipelines.py"),
    "cuda_graph_mode_on_cpu_not_refused": ("admissable_jax/envs/physics.py",
                                           'if graph_mode in CUDA_GRAPH_MODES and jax.default_backend() == "cpu":',
                                           'if False:', "test_envs.py"),
    "warp_atomics_counter_records_not_counted": ("benchmarks/warp_atomics.py",
                                                 "max(meta.counter_records_per_thread.get(target, 0), meta.max_records, 1)",
                                                 "max(meta.max_records, 1)", "test_warp_kernels.py"),
    "step_counts_in_float_notation_refused": ("admissable_jax/cli.py",
                                              "return int(number) if math.isfinite(number) and number.is_integer() else value",
                                              "return value", "test_training.py"),
    "resume_step_without_resume_ignored": ("admissable_jax/config.py", "if config.resume_step != -1 and not config.resume:",
                                           "if False:", "test_training.py"),
    "campaign_settings_unchecked": ("benchmarks/gpu_campaign.sh",
                                    '[[ -z "$value" || "$value" =~ $2 ]] || { echo',
                                    'true || { echo', "test_campaign_plan.py"),
    "policy_action_shape_unchecked": ("admissable_jax/scoring/estimators.py", "    _check_policy(env, policy_fn, params)\n",
                                      "", "test_audit.py"),
    "packed_runs_not_named": ("admissable_jax/results.py", '        unpack = (f"; are they packed in',
                              '        unpack = "" and (f"; are they packed in', "test_plots.py"),
    "audited_policy_error_unnamed": ("admissable_jax/audit/command.py", "audit_gymnasium(config.gym, _named(policy, config.policy), ks,",
                                     "audit_gymnasium(config.gym, policy, ks,", "test_audit.py"),
    "improvement_ties_count_nothing": ("admissable_jax/results.py", "return (above + 0.5 * tied).mean(axis=(-2, -1))",
                                       "return (above + 0.0 * tied).mean(axis=(-2, -1))", "test_plots.py"),
    "improvement_resamples_the_modes_together": ("admissable_jax/results.py",
                                                 "drawn = [values[rng.integers(0, len(values), (resamples, len(values)))]",
                                                 "drawn = [values[np.random.default_rng(0).integers(0, len(values), (resamples, len(values)))]",
                                                 "test_plots.py"),
    "repeatability_copies_checkpoints": ("benchmarks/repeatability.py", 'ignore=shutil.ignore_patterns("checkpoints*")',
                                         'ignore=shutil.ignore_patterns("nothing")', "test_repeatability.py"),
    # Modules no mutation had touched before: the contact-frame patch, envs of one's own, the
    # audit's sets and progress, Ant's feature names, the clean-up of folders a command made.
    "contact_frame_upstream_threshold_jax": ("admissable_jax/envs/contact_frames.py", "        norm < _MIN_NORM,",
                                             "        norm < 0.5,", "test_envs.py"),
    "contact_frame_upstream_threshold_warp": ("admissable_jax/envs/contact_frames.py", "        if norm < 1.0e-15:",
                                              "        if norm < 0.5:", "test_envs.py"),
    "own_env_truncates_a_step_late": ("admissable_jax/envs/external.py", "truncated=step_count >= self.max_episode_steps",
                                      "truncated=step_count > self.max_episode_steps", "test_external_env.py"),
    "own_env_terminates_when_told_not_to": ("admissable_jax/envs/external.py",
                                            "jnp.asarray(terminated, bool) & self.options.terminate_when_unhealthy",
                                            "jnp.asarray(terminated, bool)", "test_external_env.py"),
    "brax_env_never_terminates": ("admissable_jax/envs/external.py", "brax_state.done > 0)", "brax_state.done < 0)",
                                  "test_external_env.py"),
    "audit_drop_signed_by_the_clean_return": ("admissable_jax/audit/sets.py", "/ abs(clean_score)", "/ clean_score",
                                              "test_audit.py"),
    "audit_told_apart_from_the_pilots_starts": ("admissable_jax/audit/sets.py", "seed=seed + 1, shapley=shapley)",
                                                "seed=seed, shapley=shapley)", "test_audit.py"),
    "gymnasium_audit_gaps_paired": ("admissable_jax/audit/sets.py", "return dataclasses.replace(result, same_starts=False)",
                                    "return result", "test_audit.py"),
    "audit_beam_level_not_counted": ("admissable_jax/audit/sets.py",
                                     "return max(num_sets, beam_width * d if searched else 0)", "return num_sets",
                                     "test_audit.py"),
    "audit_mean_over_searched_finalists": ("admissable_jax/audit/sets.py", 'float("nan") if k in self.search else ', "",
                                           "test_audit.py"),
    "ant_contact_names_force_before_torque": ("admissable_jax/envs/catalog.py", 'for kind in ("torque", "force")',
                                              'for kind in ("force", "torque")', "test_plots.py"),
    "cleanup_removes_files_it_did_not_write": ("admissable_jax/errors.py",
                                               "(os.path.isfile(entry) and os.path.basename(entry) in own_files)",
                                               "os.path.isfile(entry)", "test_runs.py"),
    "audit_progress_counts_reports_not_episodes": ("admissable_jax/audit/watch.py",
                                                   "self.bar.update(max(0, finished - self.bar.n))",
                                                   "self.bar.update(finished)", "test_audit.py"),
    # More modules with one mutation or none: the loggers, the pairs' placement, the point
    # mass, the run lock, plot's folders and caption, joining a SLURM job.
    "logged_fingerprint_as_a_scalar": ("admissable_jax/loggers.py", 'key not in ("env_steps", FINGERPRINT)',
                                       'key != "env_steps"', "test_training.py"),
    "padding_pairs_read_back": ("admissable_jax/placement.py", "return [pair for pair in held if pair < self.num_pairs]",
                                "return held", "test_sharding.py"),
    "pair_state_row_not_offset": ("admissable_jax/placement.py", "return shard.data, pair - start", "return shard.data, pair",
                                  "test_sharding.py"),
    "point_mass_rewarded_before_its_step": ("admissable_jax/envs/point_mass.py",
                                            "_observation(data), jnp.exp(-jnp.sum(position**2))",
                                            "_observation(data), jnp.exp(-jnp.sum(state.data.position**2))",
                                            "test_external_env.py"),
    "own_lock_pid_taken_for_alive": ("admissable_jax/locks.py", "if not isinstance(pid, int) or pid == os.getpid():",
                                     "if not isinstance(pid, int):", "test_runs.py"),
    "plot_folders_numbered_from_1": ("admissable_jax/plot.py", "candidate, number = path, 1", "candidate, number = path, 0",
                                     "test_plots.py"),
    "one_slurm_task_joins_a_distributed_job": ("admissable_jax/placement.py",
                                               'int(environ.get("SLURM_NTASKS", "1") or 1) > 1',
                                               'int(environ.get("SLURM_NTASKS", "1") or 1) >= 1', "test_sharding.py"),
    "one_seed_captioned_with_an_interval": ("admissable_jax/plot.py",
                                            "return max(collections.Counter(run.curve for run in runs).values()) > 1",
                                            "return max(collections.Counter(run.curve for run in runs).values()) >= 1",
                                            "test_plots.py"),
    # The GPU campaign's planner (benchmarks/campaign.py): a projection too short starts a run
    # that the lease cannot finish; and the speed table's env steps per second.
    "plan_rounds_the_saves_down": ("benchmarks/campaign.py", "saves = math.ceil(scorings / checkpoint_every)",
                                   "saves = scorings // checkpoint_every", "test_campaign_plan.py"),
    "plan_without_the_first_run": ("benchmarks/campaign.py", 'once = record["compile_s"] + first_run_s(record)',
                                   'once = record["compile_s"]', "test_campaign_plan.py"),
    "plan_from_fewer_pairs": ("benchmarks/campaign.py", 'r for r in records if r["pairs"] >= len(pairs)',
                              'r for r in records if r["pairs"] >= 1', "test_campaign_plan.py"),
    "plan_from_another_device": ("benchmarks/campaign.py",
                                 'shaped = [r for r in same_shape if r.get("device") == want["device"]]',
                                 "shaped = same_shape", "test_campaign_plan.py"),
    "plan_from_the_most_pairs": ("benchmarks/campaign.py", 'fewest = min(r["pairs"] for r in shaped)',
                                 'fewest = max(r["pairs"] for r in shaped)', "test_campaign_plan.py"),
    "speed_table_steps_per_s_of_one_env": ("benchmarks/physics_throughput.py",
                                           '"env_steps_per_s": round(batch * bench.steps / env_s, 1),',
                                           '"env_steps_per_s": round(bench.steps / env_s, 1),', "test_hopper_pipelines.py"),
    "train_speed_of_one_seed": ("benchmarks/train_throughput.py",
                                "env_steps = bench.iterations * bench.num_envs * bench.seeds",
                                "env_steps = bench.iterations * bench.num_envs", "test_campaign_plan.py"),
    # What keeps finished work: the checkpoint a corrupt one's message offers, the one a
    # resume continues from; and the Warp buffers an experiment's pairs share.
    "corrupt_checkpoint_offers_the_oldest_intact": ("admissable_jax/checkpointing.py",
                                                    "older = sorted((s for s in self._manager.all_steps() if s < step), reverse=True)",
                                                    "older = sorted(s for s in self._manager.all_steps() if s < step)",
                                                    "test_runs.py"),
    "resumed_checkpoint_set_aside_too": ("admissable_jax/checkpointing.py",
                                         "newer = [later for later in self._manager.all_steps() if later > step]",
                                         "newer = [later for later in self._manager.all_steps() if later >= step]",
                                         "test_runs.py"),
    "physics_buffers_sized_for_one_pair": ("admissable_jax/run_spec.py",
                                           "max_batch=num_runs * max(config.num_envs, config.score_envs, horizon_ranker_batch(config)),",
                                           "max_batch=max(config.num_envs, config.score_envs, horizon_ranker_batch(config)),",
                                           "test_hopper_pipelines.py"),
    # Modules with few bugs before: Figure 1's lines and dots, the beam search, a loaded
    # policy, the video, the experiment's clean-up, make_env's options, and the speed step's
    # scoring round.
    "brax_benchmark_imports_mjx_first": ("benchmarks/brax_sac.py", "warp_package.use_package()\n", "",
                                         "test_campaign_plan.py"),
    "campaign_worker_known_by_its_pid_alone": ("benchmarks/gpu_campaign.sh",
                                               '  [ ! -e "/proc/$pid" ] || { grep -qa gpu_campaign.sh',
                                               '  true || { grep -qa gpu_campaign.sh', "test_campaign_plan.py"),
    "figure_line_unsmoothed": ("admissable_jax/plot.py", "        mean, low, high = mean_and_interval(smoothed)",
                               "        mean, low, high = mean_and_interval(values)", "test_plots.py"),
    "figure_dots_of_the_first_seed": ("admissable_jax/plot.py", 'ax.plot(steps, values.mean(axis=0), "."',
                                      'ax.plot(steps, values[0], "."', "test_plots.py"),
    "beam_up_to_k_finalists_of_the_last_level": ("admissable_jax/scoring/set_search.py", "        if up_to_k or size == k:",
                                                 "        if size == k:", "test_mechanism.py"),
    "beam_keeps_copies": ("admissable_jax/scoring/set_search.py",
                          "    return among & jnp.zeros(m, bool).at[row_of].set(first)", "    return among",
                          "test_training.py"),
    "beam_extends_by_a_held_feature": ("admissable_jax/scoring/set_search.py", "(kept_found[:, None] & (kept == 0))",
                                       "(kept_found[:, None] & (kept >= 0))", "test_training.py"),
    "loaded_policy_ignores_u": ("admissable_jax/policies.py", "hidden_row(hidden, self.observation_size)",
                                "hidden_row((), self.observation_size)", "test_experiment.py"),
    "loaded_policy_one_obs_as_a_batch": ("admissable_jax/policies.py",
                                         "        return actions.reshape(*obs.shape[:-1], -1)", "        return actions",
                                         "test_training.py"),
    "video_index_beyond_d_taken": ("admissable_jax/video.py", "if item.isdigit() and int(item) < len(names):",
                                   "if item.isdigit():", "test_hopper_pipelines.py"),
    "video_end_not_held": ("admissable_jax/video.py", "if held > fps:", "if held > 1:", "test_hopper_pipelines.py"),
    "experiment_folder_kept_after_a_refusal": ("admissable_jax/experiment.py",
                                               'held.callback(remove_if_unused, root, ("experiment.yaml",))',
                                               "held.callback(remove_if_unused, root, ())", "test_experiment.py"),
    "make_env_overrides_dropped_beside_options": ("admissable_jax/envs/__init__.py", "    elif option_overrides:",
                                                  "    elif False:", "test_envs.py"),
    "point_mass_records_the_asked_physics": ("admissable_jax/envs/__init__.py", '    return "jax"\n',
                                             "    return resolve_physics(physics)\n", "test_external_env.py"),
    "scoring_round_terminates_anyway": ("benchmarks/scoring_round.py", "terminate_when_unhealthy=bench.terminate)",
                                        "terminate_when_unhealthy=True)", "test_campaign_plan.py"),
    "scoring_round_counts_one_slot": ("benchmarks/scoring_round.py", "    stepped = loop_steps * slots",
                                      "    stepped = loop_steps", "test_campaign_plan.py"),
    # Cheaper score estimates and the audit's report, in words (a twentieth round).
    "estimate_bootstraps_past_the_step_limit": ("admissable_jax/scoring/value_estimates.py",
                                                "        alive = alive & ~states.terminated & (states.step_count < env.max_episode_steps)",
                                                "        alive = alive & ~states.terminated", "test_audit.py"),
    "estimate_bootstraps_ended_episodes": ("admissable_jax/scoring/value_estimates.py",
                                           "jnp.where(alive, gamma**horizon * jnp.min(q, axis=-1), 0.0)",
                                           "gamma**horizon * jnp.min(q, axis=-1)", "test_audit.py"),
    "estimate_from_other_start_states": ("admissable_jax/scoring/value_estimates.py",
                                         "jax.vmap(env.reset)(jax.random.split(rng, n_episodes))",
                                         "jax.vmap(env.reset)(jax.random.split(jax.random.fold_in(rng, 1), n_episodes))",
                                         "test_audit.py"),
    "audit_pilot_seed_named_as_the_audits": ("admissable_jax/audit/report.py", "these are seed {pilot['seed'] + 1}'s",
                                             "these are seed {pilot['seed']}'s", "test_audit.py"),
    "audit_runner_up_is_the_best_set": ("admissable_jax/audit/report.py",
                                        "the runner-up, {', '.join(gaps[1].entry.names)}, lies",
                                        "the runner-up, {', '.join(gaps[-1].entry.names)}, lies", "test_audit.py"),
    "audit_mean_drop_is_the_worsts": ("admissable_jax/audit/report.py",
                                      "{drop_below_clean(result.clean_score, result.mean(k)):.1f}% below clean",
                                      "{drop_below_clean(result.clean_score, worst[0].score):.1f}% below clean",
                                      "test_audit.py"),
    "audit_small_gaps_read_zero": ("admissable_jax/audit/report.py", "abs(value) >= 0.05 else", "abs(value) >= 0.0 else",
                                   "test_audit.py"),
    # Modules with one or two bugs before (a twenty-first round): the physics (reset
    # kinematics, contact forces, RK4, Warp's buffers), FIGURE1.md's words and cost line, the
    # env catalog, and the command line.
    "reset_normalizes_the_quaternion": ("admissable_jax/envs/physics.py",
                                        "data = mjx.kinematics(self.model, data).replace(qpos=qpos)",
                                        "data = mjx.kinematics(self.model, data)", "test_envs.py"),
    "jax_physics_skips_contact_forces": ("admissable_jax/envs/physics.py", 'if self.contact_forces and self.impl == "jax":',
                                         "if False:", "test_envs.py"),
    "rk4_first_stage_unweighted": ("admissable_jax/envs/physics.py", "pick(b_i * term, total + b_i * term)",
                                   "pick(term, total + b_i * term)", "test_envs.py"),
    "warp_contacts_for_one_world": ("admissable_jax/envs/physics.py",
                                    "naconmax=max(1, self.contacts_per_world) * max_batch,",
                                    "naconmax=max(1, self.contacts_per_world),", "test_hopper_pipelines.py"),
    "warp_overflow_never_seen": ("admissable_jax/envs/physics.py",
                                 "return (data._impl.overflow & self._capacity_mask) != 0",
                                 "return (data._impl.overflow & self._capacity_mask) < 0", "test_hopper_pipelines.py"),
    "figure1_above_sb3_at_its_mean": ("benchmarks/figure1.py", "elif low > reference + spread:", "elif low > reference:",
                                      "test_figure1.py"),
    "figure1_uniform_win_read_as_adversarial": ("benchmarks/figure1.py", '"uniform higher": "uniform training is higher',
                                                '"adversarial higher": "uniform training is higher', "test_figure1.py"),
    "figure1_projects_from_the_first_rounds": ("benchmarks/figure1.py", "late = rounds[-10:]", "late = rounds[:10]",
                                               "test_figure1.py"),
    "figure1_steps_of_the_longest_run": ("benchmarks/figure1.py", "steps = min(int(run.env_steps[-1]) for run in runs)",
                                         "steps = max(int(run.env_steps[-1]) for run in runs)", "test_figure1.py"),
    "figure1_table_without_auc": ("benchmarks/figure1.py", "for d in differences[:2]]", "for d in differences[:1]]",
                                  "test_figure1.py"),
    "gymnasium_ids_not_env_names": ("admissable_jax/envs/catalog.py", "key = _ALIASES.get(key, key)", "key = key",
                                    "test_envs.py"),
    "own_env_of_size_zero_taken": ("admissable_jax/envs/catalog.py", "size < 1:", "size < 0:", "test_external_env.py"),
    "own_env_feature_names_uncounted": ("admissable_jax/envs/catalog.py", "if len(names) != size:", "if False:",
                                        "test_external_env.py"),
    "settotalmass_warning_printed": ("admissable_jax/envs/catalog.py", 'if "settotalmass" not in message:', "if True:",
                                     "test_envs.py"),
    "own_env_folder_keeps_its_case": ("admissable_jax/envs/catalog.py", 'name.rpartition(":")[2].lower() if',
                                      'name.rpartition(":")[2] if', "test_external_env.py"),
    "step_counts_as_floats_refused": ("admissable_jax/cli.py",
                                      "return int(number) if math.isfinite(number) and number.is_integer() else value",
                                      "return value", "test_training.py"),
    "empty_value_read_as_none": ("admissable_jax/cli.py",
                                 """argv = [f"{arg}''" if arg.endswith("=") else arg for arg in argv]""",
                                 "argv = list(argv)", "test_training.py"),
    "sigterm_kills_without_cleanup": ("admissable_jax/cli.py", "(signal.SIGTERM,))", "())", "test_runs.py"),
    "config_file_sets_the_run_location": ("admissable_jax/cli.py", "if key in config_file.taken}",
                                          "if key in config_file.taken | config_file.skipped}", "test_training.py"),
    # Modules with few bugs before (a twenty-second round): the run directory's records and
    # resume checks, a finished run resumed, the audit command, the experiment's settings file,
    # the figures' moving-average window.
    "corrupt_line_read_as_torn": ("admissable_jax/run_directory.py", "            if number < len(lines):\n",
                                  "            if False:\n", "test_runs.py"),
    "grad_speed_of_one_update_per_iteration": ("admissable_jax/run_directory.py",
                                               "float(learned.sum()) * config.updates_per_iteration / train_seconds",
                                               "float(learned.sum()) / train_seconds", "test_runs.py"),
    "finished_run_not_resumable": ("admissable_jax/run_directory.py", "        if config.total_steps < reached:\n",
                                   "        if config.total_steps <= reached:\n", "test_runs.py"),
    "resume_without_a_run_not_refused_first": ("admissable_jax/run_directory.py",
                                               "        if config.resume and not os.path.exists(config_path):  # checked before anything is created\n",
                                               "        if False:\n", "test_runs.py"),
    "finished_run_trains_on": ("admissable_jax/host_loop.py",
                               "if resume_from is not None and resume_from >= config.planned_steps:",
                               "if resume_from is not None and resume_from > config.planned_steps:", "test_runs.py"),
    "audit_experiment_at_the_latest_step": ("admissable_jax/audit/command.py",
                                            "step = None if config.step < 0 else config.step", "step = None",
                                            "test_experiment.py"),
    "audit_counts_the_worst_as_not_told_apart": ("admissable_jax/audit/command.py",
                                                 "tied = sum(gap.tied for gap in result.gaps_to_worst(k)[1:])",
                                                 "tied = sum(gap.tied for gap in result.gaps_to_worst(k))", "test_audit.py"),
    "audit_top_zero_taken": ("admissable_jax/audit/command.py", "if config.top < 1:", "if config.top < 0:",
                             "test_audit.py"),
    "audit_policy_slots_ignored": ("admissable_jax/audit/command.py", "num_envs=config.slots or 8,", "num_envs=8,",
                                   "test_audit.py"),
    "experiment_yaml_never_written": ("admissable_jax/experiment.py",
                                      "        if jax.process_index() == 0:\n            OmegaConf.save",
                                      "        if jax.process_index() == 1:\n            OmegaConf.save",
                                      "test_experiment.py"),
    "paper_window_uncapped": ("admissable_jax/plot.py",
                              "return max(1, min(PAPER_WINDOW, records * PAPER_WINDOW // PAPER_RECORDS))",
                              "return max(1, records * PAPER_WINDOW // PAPER_RECORDS)", "test_plots.py"),
    "window_longer_than_the_runs": ("admissable_jax/plot.py", "    return min(window, records)\n",
                                    "    return window\n", "test_plots.py"),
    # What keeps finished work, again (a twenty-third round): a failed save's clean-up, the
    # checkpoints a restore sets aside, another version's layout, a full disk's reason, a resume
    # of records without checkpoints.
    "failed_save_leaves_its_partial_write": ("admissable_jax/checkpointing.py", 'if ".orbax-checkpoint-tmp" in name:',
                                             "if False:", "test_runs.py"),
    "restored_checkpoint_set_aside": ("admissable_jax/checkpointing.py",
                                      "newer = [later for later in self._manager.all_steps() if later > step]",
                                      "newer = [later for later in self._manager.all_steps() if later >= step]",
                                      "test_runs.py"),
    "other_layout_read_as_corrupt": ("admissable_jax/checkpointing.py", "        if saved != len(abstract):\n",
                                     "        if False:\n", "test_training.py"),
    "disk_error_found_by_cause_only": ("admissable_jax/checkpointing.py", "seen = seen.__cause__ or seen.__context__",
                                       "seen = seen.__cause__", "test_runs.py"),
    "records_without_checkpoints_started_over": ("admissable_jax/host_loop.py", "            if reached:\n",
                                                 "            if False:\n", "test_training.py"),
    # The Gymnasium wrappers, again (a twenty-fourth round): bad scores, SB3's (action, state)
    # tuple, the seeds that make a wrapped env's u reproducible, ε's range.
    "wrapper_update_takes_non_finite_scores": ("admissable_jax/wrappers.py", "        if not np.isfinite(scores).all():\n",
                                               "        if False:\n", "test_wrappers.py"),
    "score_policy_takes_sb3_tuple_whole": ("admissable_jax/wrappers.py",
                                           "actions = np.asarray(actions[0] if isinstance(actions, tuple) else actions)",
                                           "actions = np.asarray(actions)", "test_wrappers.py"),
    "wrapper_reset_seed_ignored": ("admissable_jax/wrappers.py",
                                   "        if seed is not None:\n            self._rng = np.random.default_rng([seed, 0x6D61736B])",
                                   "        if False:\n            self._rng = np.random.default_rng([seed, 0x6D61736B])",
                                   "test_wrappers.py"),
    "adversarial_wrapper_seed_ignored": ("admissable_jax/wrappers.py", "        self._rng = np.random.default_rng(seed)\n",
                                         "        self._rng = np.random.default_rng()\n", "test_wrappers.py"),
    "wrapper_epsilon_zero_taken": ("admissable_jax/wrappers.py", "        if not 0 < epsilon < np.inf:\n",
                                   "        if not 0 <= epsilon < np.inf:\n", "test_wrappers.py"),
}


def copy_tree(destination: str) -> None:
    """The working tree's tracked and untracked (not ignored) files, as they are now, in a
    git repository of their own (staged, not committed)."""
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=REPO, check=True,
                            capture_output=True, text=True).stdout.split("\0")
    for path in filter(None, listed):
        if os.path.isfile(os.path.join(REPO, path)):
            os.makedirs(os.path.dirname(os.path.join(destination, path)), exist_ok=True)
            shutil.copy2(os.path.join(REPO, path), os.path.join(destination, path))
    # Tests that list the tree by git (the device packs' room) must see the same files.
    for command in (["git", "init", "-q"], ["git", "add", "-A"]):
        subprocess.run(command, cwd=destination, check=True, capture_output=True)


def run_tests(tree: str, paths: list[str]) -> tuple[bool, list[str], str]:
    """(whether they all passed, the failed tests' ids, the first failed test's reason, or else
    pytest's first ERROR line or its last line) for pytest on ``paths`` of ``tree``, stopping
    at the first failure."""
    # COLUMNS: pytest cuts its summary's lines to the terminal's width, and with them the reason.
    env = dict(os.environ, PYTHONPATH=tree, JAX_PLATFORMS="cpu", COLUMNS="1000")
    # test_mutation_list.py checks this list against the tree, which a written mutation changes:
    # it fails for every mutation, so it is no catch.
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "--rootdir", tree,
                             "-c", os.path.join(tree, "pyproject.toml"),
                             "--ignore", os.path.join(tree, "tests", "test_mutation_list.py"), *paths],
                            cwd=tree, env=env, capture_output=True, text=True)
    # The short summary's lines, "FAILED <id> - <reason>" (an id may hold spaces), not logged ERRORs.
    summary = [rest.partition(" - ") for kind, _, rest in (line.partition(" ") for line in result.stdout.splitlines())
               if kind in ("FAILED", "ERROR")]
    failed = [(test_id, reason) for test_id, _, reason in summary if "::" in test_id]
    lines = [line.strip() for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    said = failed[0][1] if failed else next((line for line in lines if line.startswith("ERROR ")), lines[-1] if lines else "")
    return result.returncode == 0, [test_id for test_id, _ in failed], said


def check(name: str) -> dict:
    """Write mutation ``name`` into a copy of the tree and run its test file, then the suite."""
    path, text, replacement, first_file = MUTATIONS[name]
    start = time.time()
    with tempfile.TemporaryDirectory(prefix="mutation-") as tree:
        copy_tree(tree)
        source = open(os.path.join(tree, path)).read()
        if source.count(text) != 1:
            raise SystemExit(f"mutation {name}: {path} holds its text {source.count(text)} times, not once: update it")
        with open(os.path.join(tree, path), "w") as file:
            file.write(source.replace(text, replacement))
        imported = subprocess.run([sys.executable, "-c", "import admissable_jax; print(admissable_jax.__file__)"],
                                  cwd=tree, env=dict(os.environ, PYTHONPATH=tree), capture_output=True, text=True).stdout
        if not os.path.realpath(imported.strip()).startswith(os.path.realpath(tree)):
            raise SystemExit(f"the tests would import admissable_jax from {imported.strip()}, not the mutated copy")
        passed, failed, summary = run_tests(tree, [os.path.join(tree, "tests", first_file)])
        if passed:
            passed, failed, summary = run_tests(tree, [os.path.join(tree, "tests")])
        # pytest stopped at a first failure (-x) can leave a process of this tree running (the
        # campaign smoke test's worker runs in a session of its own): ended before its tree goes.
        subprocess.run(["pkill", "-f", tree], capture_output=True)
    row = {"mutation": name, "file": path, "caught": bool(failed), "by": failed[:3], "seconds": round(time.time() - start)}
    if failed:  # what the test said, where pytest's summary gives it: a flaky catch shows here
        row.update({"why": summary[:200]} if summary else {})
    elif not passed:  # pytest stopped without failing a test (a collection error, a crash): no catch
        row["pytest"] = summary
    return row


def main(names: list[str]) -> int:
    unknown = [name for name in names if name not in MUTATIONS]
    if unknown:
        print(f"unknown mutation {unknown[0]!r}: the names are MUTATIONS' keys in tests/mutations.py", file=sys.stderr)
        return 2
    survivors = []
    for name in names or list(MUTATIONS):
        row = check(name)
        print(json.dumps(row), flush=True)
        if not row["caught"]:
            survivors.append(name)
    if survivors:
        print(f"no test failed for: {', '.join(survivors)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

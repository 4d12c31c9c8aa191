"""Which sensors break a policy? A robustness audit over every set of k hidden features.

    python -m admissable_jax.audit RUN_DIR k=1,2 episodes=50 out=DIR [step=N]
    python -m admissable_jax.audit EXPERIMENT_DIR k=1,2      # every pair, then comparison.md
    python -m admissable_jax.audit RUN_DIR RUN_DIR ... k=1   # each run, then comparison.md of their curves
    python -m admissable_jax.audit policy=MODULE:NAME gym=Hopper-v5 k=1,2   # any Python policy

For every u with |u| in ``k`` (all C(d, |u|) sets, scored exactly: one batched rollout for
all of them and the clean case, N = ``episodes`` deterministic episodes each from the same N
start states, as the paper scores), the audit reports a_u with its 95% confidence interval
(Student's t over the N returns) and the drop from the clean return in %. It writes

- ``DIR/report.md``: the worst sets per k, with the env's feature names, on one page;
- ``DIR/audit.json``: every number (every set's a_u, CI, drop, the N returns, and its gap to the worst);
- ``DIR/scores_k1.png``: a bar chart of a_u per hidden feature (k = 1);
- ``DIR/pairs_k2.png``: a d × d heatmap of a_ij (k = 2).

Is the worst set really the worst, or did N episodes not tell it apart? Each row also gives
its a_u's gap above the worst with a 95% interval, paired episode by episode (every set's
episode i starts from one state, so the gap carries no reset noise; Welch's t for a Gymnasium
env's own resets), and the report names the sets not told apart from the worst, with about
how many episodes per set would tell the worst from the runner-up; ``tell_apart=true`` audits
with that many (a pilot of ``episodes`` per set chooses N, a second audit from fresh start
states is written).

``shapley=M`` (or ``exact``) adds what each feature is worth to the policy: its Shapley value
in the game whose coalitions are the visible features (:mod:`admissable_jax.scoring.attribution`;
exact where the 2^d coalitions are fewer than M random feature orders would value), beside the loss
of hiding it alone, in the same rollout; ``DIR/shapley.png`` and a section of the report.

``score_estimator=critic`` or ``horizon`` audits with the run's critic instead (cheaper;
discounted values, see :mod:`admissable_jax.scoring`); the report says which.

Where C(d, k) sets are too many (Ant: 5,460 pairs), ``search=beam`` finds the worst sets of
each k > 1 by beam search of width ``beam_width`` (:mod:`admissable_jax.scoring.set_search`),
ranking the candidates by ``ranker`` (rollout, or the critic's cheaper estimates), and
scores only the finalists by ``score_estimator`` (by default rollouts confirm them): at most
d + (k − 1) · b · d sets ranked instead of C(d, k). k = 1 is always scored exactly.

Given an experiment's folder, every pair is audited so (into ``PAIR/audit-step<STEP>``, or
``out/PAIR``) and ``comparison.md`` (in ``EXPERIMENT/audit-step<STEP>`` or ``out``) sets the
modes side by side per k: each pair's worst a_u and mean a_u over the sets, mean ± 95%
interval over seeds, and adversarial − uniform with Welch's interval; ``comparison.png``
draws the worst
(:func:`audit_experiment`). Given several run directories, each run is audited into its own
folder and ``comparison.md`` (in ``audit-comparison`` or ``out``) sets their curves side by
side as the experiment's modes are, a curve being a mode and the settings the runs differ in,
as ``plot`` names its curves (:func:`audit_runs`).

``fail_at=T`` lets every set's sensors fail at env step T of each episode, every feature seen
before it, where the paper hides u from the start (a sensor that dies mid-run); a comma list
(``fail_at=0,50,100``) audits the policy (or an experiment's pairs) at each step, then writes
``failure_times.md`` and ``.png``: the worst and mean a_u by failure step, and each single
feature's (an experiment: the modes' worst a_u by step, adversarial − uniform at each;
:func:`audit_failure_times`).

In Python, :func:`audit` takes any JAX ``policy_fn(params, masked_obs) -> action`` on any of
our envs, :func:`audit_gymnasium` any Python policy on any Gymnasium env (Stable-Baselines3,
CleanRL, PyTorch), and :func:`write_audit` writes either's files.

The package's rooms: :mod:`~admissable_jax.audit.sets` scores and ranks the sets (the audit
itself), :mod:`~admissable_jax.audit.report` writes what an audit found, and
:mod:`~admissable_jax.audit.command` is the command line.
"""

from admissable_jax.audit.command import AuditConfig, audit_experiment, audit_failure_times, audit_over_training, \
    audit_python_policy, audit_run, audit_runs, main
from admissable_jax.audit.report import compare_modes, write_audit
from admissable_jax.audit.sets import AuditResult, GapToWorst, SetScore, audit, audit_gymnasium

__all__ = ["AuditConfig", "AuditResult", "GapToWorst", "SetScore", "audit", "audit_experiment", "audit_failure_times",
           "audit_gymnasium", "audit_over_training", "audit_python_policy", "audit_run", "audit_runs", "compare_modes", "main",
           "write_audit"]

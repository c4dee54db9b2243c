from rflow.bench import bench_flow

TIMINGS = ("train_epoch_s", "flow_step_ms", "closed_loop_step_ms", "rollout_1000_ms", "rollouts_100x1000_ms")


def test_quick_flow_benchmark_times_every_path():
    result = bench_flow(quick=True)
    assert all(result[key] > 0 for key in TIMINGS)
    # the policy's tick is two lookahead steps of two models: it cannot be cheaper than one step of one
    assert result["closed_loop_step_ms"] > result["flow_step_ms"]

"""Made-up results of the benchmarks, for the checks of their logic and of the pages they write."""

# docs/performance.md's header: the machine a run was made on.
MACHINE = {'date': 'today', 'commit': 'abc', 'cores': 2, 'cpu': 'x', 'python': '3', 'numpy': '2',
           'rclpy': '7', 'rmw': 'r', 'rmw_fastrtps_cpp': '8', 'load_start': 0.1, 'load_end': 0.2}


def node_runs(filter_us, relay_us):
    """``bench.imu_filter_cpu.measure``'s runs of the node and the relay at these CPU figures."""
    def run(us):
        return {'cpu_us_per_sample': us, 'samples': 8000, 'fields': 800, 'outputs': 8000,
                'achieved_rate_hz': 999.0, 'load': (1.0, 1.5)}
    return {'imu_filter': [run(x) for x in filter_us], 'relay': [run(x) for x in relay_us]}


def node_result(filter_us, relay_us, executor='events'):
    """``bench.imu_filter_cpu.compare``'s result for those runs."""
    from bench.imu_filter_cpu import summarize
    runs = node_runs(filter_us, relay_us)
    result = {'executor': executor, 'rate': 1000.0, 'mag_rate': 100.0, 'seconds': 8.0,
              'rounds': len(filter_us), 'runs': runs}
    result.update(summarize(runs))
    return result

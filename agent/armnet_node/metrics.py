"""The agent's Prometheus metrics, on a registry per agent (no module-level state)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server


class AgentMetrics:
    def __init__(self, registry: CollectorRegistry | None = None) -> None:
        self.registry = registry or CollectorRegistry()
        r = self.registry
        self.jobs_started = Counter("armnet_agent_jobs_started_total", "jobs whose container started", registry=r)
        self.jobs_adopted = Counter(
            "armnet_agent_jobs_adopted_total", "running jobs re-adopted after an agent restart", registry=r
        )
        self.jobs_finished = Counter(
            "armnet_agent_jobs_finished_total", "jobs that reached a terminal phase", ["outcome"], registry=r
        )
        self.job_duration = Histogram(
            "armnet_agent_job_duration_seconds", "running -> terminal",
            buckets=(1, 5, 15, 30, 60, 120, 300, 900, 3600, 14400), registry=r,
        )
        self.launch_latency = Histogram(
            "armnet_agent_launch_latency_seconds", "seen dispatched -> running (container started)",
            buckets=(0.25, 0.5, 1, 2, 5, 10, 30, 60), registry=r,
        )
        self.timeouts = Counter("armnet_agent_job_timeouts_total", "jobs that hit their deadline", registry=r)
        self.interlock_trips = Counter(
            "armnet_agent_interlock_trips_total", "jobs whose connector tripped the interlock", ["reason"], registry=r
        )
        self.heartbeat_age = Gauge(
            "armnet_agent_heartbeat_age_seconds", "seconds since the cell's last successful heartbeat write",
            ["cell"], registry=r,
        )
        self.follower_cancels = Counter(
            "armnet_agent_follower_cancels_total",
            "non-detached jobs cancelled because their following client stopped sending heartbeats", registry=r,
        )
        self.preemptions = Counter(
            "armnet_agent_preemptions_total",
            "runs ended preempted for another job (status.preemption), by where the stop came: episode_end (the "
            "job's rollout ended, or none was open) or episode_wait (no boundary within episodeWaitSeconds: the "
            "agent opened the grace window itself)", ["stopped_at"], registry=r,
        )
        self.lines_published = Counter(
            "armnet_agent_lines_published_total", "output lines handed to the stream publisher", registry=r
        )
        self.job_log_reads = Counter(
            "armnet_agent_job_log_reads_total",
            "jobs whose output was read from the engine's log file (file) or the slower Docker API follow "
            "that may reorder an exit burst (engine_api)", ["via"], registry=r,
        )
        self.rollout_verdicts = Counter(
            "armnet_agent_rollout_verdicts_total",
            "cell operators' rollout verdicts passed to jobs and recorded in status.rollouts", ["outcome"],
            registry=r,
        )
        self.auto_resets = Counter(
            "armnet_agent_auto_resets_total",
            "scripted resets (Cell spec.reset.mode Scripted) of ended jobs, by outcome: worked (the completion "
            "monitor judged the scene back at its start, nobody involved), try_failed (one try that did not; each "
            "try counts), fell_back (every try failed: the person at the cell was asked, alert), stopped (the "
            "interlock stopped it: a safety refusal, the deadline, a cancel)", ["outcome"], registry=r,
        )
        self.completion_overrules = Counter(
            "armnet_completion_overrules_total",
            "rollouts whose cell operator's outcome differs from the completion monitor's verdict (status.rollouts: "
            "markedBy an operator, monitor.outcome the other): the monitor's misses, kept for retraining", registry=r,
        )
        self.cell_record_items = Counter(
            "armnet_agent_cell_record_items_total",
            "what the connectors kept in the cell's record of ended jobs, by part (trace_rows: servo trace rows, "
            "video_frames: camera video frames, rollout_pictures) and outcome (kept, dropped: the writer was behind, "
            "a cap was reached or a write failed; alert on a rising dropped)", ["part", "outcome"], registry=r,
        )
        self.lines_dropped = Counter(
            "armnet_agent_lines_dropped_total", "output lines the publisher refused", registry=r
        )

        self.outputs = Counter(
            "armnet_agent_job_outputs_total",
            "ended jobs' output directories: uploaded (whole), incomplete (a file changed while it was sent), "
            "too_large (over the cap: nothing stored), discarded (no object store configured), empty",
            ["outcome"], registry=r,
        )
        self.output_bytes = Counter(
            "armnet_agent_job_output_bytes_uploaded_total", "bytes of job outputs sent to the object store",
            registry=r,
        )
        self.output_upload_failures = Counter(
            "armnet_agent_job_output_upload_failures_total",
            "job output uploads that failed and wait for a retry: unavailable (the store did not answer), "
            "misconfigured (bucket or keys refused), error (the agent's own)", ["reason"], registry=r,
        )
        self.outputs_pending = Gauge(
            "armnet_agent_job_outputs_pending",
            "ended jobs whose output is still on the robot host, waiting for its upload", registry=r,
        )

        self.pod_start_latency = Histogram(
            "armnet_agent_pod_start_latency_seconds",
            "pod launcher: pod created -> the job container started (connector sidecar ready first)",
            buckets=(0.5, 1, 2, 3, 5, 10, 20, 30, 60), registry=r,
        )
        self.pod_failures = Counter(
            "armnet_agent_pod_failures_total",
            "pod launcher: job pods that ended without a job result (image missing, deadline, connector restarted)",
            ["reason"], registry=r,
        )
        self.connector_restarts = Counter(
            "armnet_agent_connector_restarts_total",
            "pod launcher: jobs whose connector sidecar was restarted by the kubelet (the job fails)", registry=r,
        )

        self.device_plugin_registrations = Counter(
            "armnet_agent_device_plugin_registrations_total",
            "pod launcher: registrations of a cell's device plugin with the kubelet (again after each kubelet "
            "restart), ok or failed", ["cell", "result"], registry=r,
        )
        self.device_plugin_allocations = Counter(
            "armnet_agent_device_plugin_allocations_total",
            "pod launcher: the kubelet's Allocate calls for a cell's devices, granted or refused (a device missing)",
            ["cell", "result"], registry=r,
        )
        self.device_healthy = Gauge(
            "armnet_agent_device_healthy",
            "0 while the cell's devices are lost (a serial port or camera path missing or no character device "
            "for the debounce: HardwareReady DeviceLost, the device plugin reports Unhealthy), else 1",
            ["cell"], registry=r,
        )
        self.device_lost_jobs = Counter(
            "armnet_agent_jobs_device_lost_total",
            "running jobs ended failed with \"device lost\" because a device of their cell vanished", registry=r,
        )

        self.telemetry_frames = Counter(
            "armnet_agent_telemetry_frames_total",
            "camera frames for the cell operator's page: published (JPEG on NATS) or failed (no frame, not encodable)",
            ["result"], registry=r,
        )
        self.telemetry_reads = Counter(
            "armnet_agent_telemetry_servo_reads_total",
            "servo telemetry reads for the cell operator's page: published, or skipped (a launch holds the bus, "
            "a job is stopping, or a pod job's observer socket did not answer)", ["result"], registry=r,
        )
        self.observer_requests = Counter(
            "armnet_agent_sidecar_observer_requests_total",
            "pod launcher: requests to a job's connector observer socket (telemetry, rollout events): ok, "
            "unreachable (the socket cannot be connected: the DaemonSet's kubelet mount or --kubelet-root-dir), "
            "failed (the connection broke or the connector refused), invalid (a reply of the wrong shape)",
            ["result"], registry=r,
        )
        self.sidecar_inputs = Counter(
            "armnet_agent_sidecar_inputs_total",
            "pod launcher: operator inputs and cancels sent to a job's connector sidecar (agent.sock), by op: "
            "applied, dropped (the connector refused it as stale: no reset waiting, another rollout), failed "
            "(the socket did not answer or refused the request)", ["op", "result"], registry=r,
        )

    def serve(self, port: int, address: str) -> None:
        if port:
            start_http_server(port, addr=address, registry=self.registry)

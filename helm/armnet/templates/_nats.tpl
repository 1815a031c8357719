{{/* nats-server configuration of the bundled NATS (see nats.yaml for the layout). */}}
{{- define "armnet.natsConfig" -}}
{{- $d := .Values.nats.deploy -}}
port: 4222
http_port: 8222
server_name: armnet-nats
jetstream {
  store_dir: /data/jetstream
  # nats-server units: K, M, G, T (powers of 1024), like the PVC's Ki, Mi, Gi, Ti
  max_file_store: {{ $d.storageSize | trimSuffix "i" }}
}
{{- if $d.auth.enabled }}
accounts {
  ARMNET {
    jetstream: enabled
    users: [
      {
        user: agent
        password: $NATS_AGENT_PASSWORD
        permissions: {
          # fms.<cell>.reset.requested: a job's reset waits, for the cell operators' page;
          # telemetry.<cell>.>: camera frames and servo readings for that page.
          publish: ["logs.>", "fms.*.reset.requested", "telemetry.>", "$JS.API.>", "_INBOX.>"]
          subscribe: ["teleop.>", "fms.>", "clients.>", "_INBOX.>"]
        }
      }
      {
        user: fms
        password: $NATS_FMS_PASSWORD
        permissions: {
          # Operator inputs to jobs (reset.confirm, outcome), the agents' reset notices and
          # cells' telemetry (frames, servo readings); nothing else: the page shows no logs,
          # and it sends no requests (no inbox). Tenants never hear telemetry.>.
          publish: ["fms.>"]
          subscribe: ["fms.*.reset.requested", "telemetry.>"]
        }
      }
      {{- range $d.auth.tenants }}
      {
        user: {{ printf "tenant-%s" . | quote }}
        password: {{ printf "$NATS_TENANT_%s_PASSWORD" (. | upper | replace "-" "_") }}
        permissions: {
          # Only its own namespace: live output, teleop input, and stream consumers
          # whose filter subject is inside logs.{{ . }}.> (the server checks the filter
          # in the subject of the CONSUMER.CREATE request). Fetching from, reading and
          # deleting a consumer need its name: the client names each one with 128 random
          # bits and tenants cannot list consumers, so only their creator can use them.
          # clients.<ns>.> carries the heartbeats of a client following a non-detached job.
          publish: [{{ printf "teleop.%s.>" . | quote }}, {{ printf "clients.%s.>" . | quote }}, {{ printf "$JS.API.CONSUMER.CREATE.ARMNET_LOGS.*.logs.%s.>" . | quote }}, "$JS.API.STREAM.INFO.ARMNET_LOGS", "$JS.API.CONSUMER.MSG.NEXT.ARMNET_LOGS.*", "$JS.API.CONSUMER.INFO.ARMNET_LOGS.*", "$JS.API.CONSUMER.DELETE.ARMNET_LOGS.*"]
          # Replies only on its own inbox prefix: the client sets inbox_prefix "_INBOX.{{ . }}"
          # (a shared _INBOX.> would let one tenant read another's replies).
          subscribe: [{{ printf "logs.%s.>" . | quote }}, {{ printf "_INBOX.%s.>" . | quote }}]
        }
      }
      {{- end }}
    ]
  }
}
{{- end }}
{{- end -}}

{{/* Chart name, overridable. */}}
{{- define "armnet.name" -}}
{{- default .Chart.Name .Values.nameOverride | trunc 63 | trimSuffix "-" -}}
{{- end -}}

{{/* Resource name prefix: the release name, plus the chart name unless it is already in it. */}}
{{- define "armnet.fullname" -}}
{{- if .Values.fullnameOverride -}}
{{- .Values.fullnameOverride | trunc 63 | trimSuffix "-" -}}
{{- else -}}
{{- $name := include "armnet.name" . -}}
{{- if contains $name .Release.Name -}}
{{- .Release.Name | trunc 63 | trimSuffix "-" -}}
{{- else -}}
{{- printf "%s-%s" .Release.Name $name | trunc 63 | trimSuffix "-" -}}
{{- end -}}
{{- end -}}
{{- end -}}

{{- define "armnet.labels" -}}
helm.sh/chart: {{ printf "%s-%s" .Chart.Name .Chart.Version | replace "+" "_" }}
app.kubernetes.io/name: {{ include "armnet.name" . }}
app.kubernetes.io/instance: {{ .Release.Name }}
app.kubernetes.io/version: {{ .Chart.AppVersion | quote }}
app.kubernetes.io/managed-by: {{ .Release.Service }}
{{- with .Values.commonLabels }}
{{ toYaml . }}
{{- end }}
{{- end -}}

{{/* Selector labels of one component: include "armnet.selector" (list . "operator") */}}
{{- define "armnet.selector" -}}
{{- $ := index . 0 -}}
app.kubernetes.io/name: {{ include "armnet.name" $ }}
app.kubernetes.io/instance: {{ $.Release.Name }}
app.kubernetes.io/component: {{ index . 1 }}
{{- end -}}

{{- define "armnet.operatorImage" -}}
{{- printf "%s:%s" .Values.image.operatorRepository (default .Chart.AppVersion .Values.image.tag) -}}
{{- end -}}

{{- define "armnet.agentImage" -}}
{{- printf "%s:%s" .Values.image.agentRepository (default .Chart.AppVersion .Values.image.tag) -}}
{{- end -}}

{{- define "armnet.connectorImage" -}}
{{- $c := .Values.agent.connectorImage -}}
{{- printf "%s:%s" (default .Values.image.agentRepository $c.repository) (default (default .Chart.AppVersion .Values.image.tag) $c.tag) -}}
{{- end -}}

{{- define "armnet.operatorAccount" -}}{{ include "armnet.fullname" . }}-operator{{- end -}}
{{- define "armnet.agentAccount" -}}{{ include "armnet.fullname" . }}-agent{{- end -}}

{{/* The NATS URL the agent gets when NATS is not from a Secret ("" when none). */}}
{{- define "armnet.natsUrl" -}}
{{- if .Values.nats.deploy.enabled -}}
{{- if .Values.nats.deploy.auth.enabled -}}
nats://agent:$(NATS_AGENT_PASSWORD)@{{ include "armnet.fullname" . }}-nats.{{ .Release.Namespace }}.svc:4222
{{- else -}}
nats://{{ include "armnet.fullname" . }}-nats.{{ .Release.Namespace }}.svc:4222
{{- end -}}
{{- else -}}
{{- .Values.nats.url -}}
{{- end -}}
{{- end -}}

{{/* Comma-separated job namespaces ("" = all). */}}
{{- define "armnet.jobNamespaces" -}}
{{- $names := list -}}
{{- range .Values.jobNamespaces }}{{ $names = append $names .name }}{{ end -}}
{{- join "," $names -}}
{{- end -}}

{{/* The projected service-account token: only where a container talks to the API server,
     short-lived, instead of the auto-mounted legacy path on every container. */}}
{{- define "armnet.apiTokenVolume" -}}
- name: kube-api-access
  projected:
    defaultMode: 0444
    sources:
      - serviceAccountToken:
          path: token
          expirationSeconds: 3607
      - configMap:
          name: kube-root-ca.crt
          items: [{key: ca.crt, path: ca.crt}]
      - downwardAPI:
          items:
            - path: namespace
              fieldRef: {fieldPath: metadata.namespace}
{{- end -}}
{{- define "armnet.apiTokenMount" -}}
- name: kube-api-access
  mountPath: /var/run/secrets/kubernetes.io/serviceaccount
  readOnly: true
{{- end -}}
{{- /* The object store of job outputs (docs/outputs.md): the agent uploads there, the operator
removes a job's outputs with the job at its TTL. Both get the same variables; the keys come from
"secret" (the agent's artifacts.credentialsSecret, which needs only to write; the operator's
artifacts.operatorCredentialsSecret, which needs to list and delete, else the same Secret). */}}
{{- define "armnet.artifacts.env" -}}
{{- with .artifacts }}
{{- if .bucket }}
{{- if not .credentialsSecret }}
{{- fail "artifacts.bucket is set but artifacts.credentialsSecret is not: name the Secret (keys accessKeyId, secretAccessKey) with the keys to the bucket" }}
{{- end }}
- {name: ARMNET_ARTIFACTS_BUCKET, value: {{ .bucket | quote }}}
- {name: ARMNET_ARTIFACTS_ENDPOINT, value: {{ .endpoint | quote }}}
- {name: ARMNET_ARTIFACTS_REGION, value: {{ .region | quote }}}
- name: ARMNET_ARTIFACTS_ACCESS_KEY_ID
  valueFrom: {secretKeyRef: {name: {{ $.secret }}, key: accessKeyId}}
- name: ARMNET_ARTIFACTS_SECRET_ACCESS_KEY
  valueFrom: {secretKeyRef: {name: {{ $.secret }}, key: secretAccessKey}}
{{- end }}
{{- end }}
{{- end -}}

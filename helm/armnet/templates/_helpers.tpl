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
{{- $root := .root }}
{{- with $root.Values.artifacts }}
{{- if .bucket }}
{{- if not .credentialsSecret }}
{{- fail "artifacts.bucket is set but artifacts.credentialsSecret is not: name the Secret (keys accessKeyId, secretAccessKey) with the keys to the bucket" }}
{{- end }}
{{- $endpoint := .endpoint }}
{{- if .deploy.enabled }}
{{- $endpoint = printf "http://%s-store.%s.svc:8333" (include "armnet.fullname" $root) $root.Release.Namespace }}
{{- end }}
- {name: ARMNET_ARTIFACTS_BUCKET, value: {{ .bucket | quote }}}
- {name: ARMNET_ARTIFACTS_ENDPOINT, value: {{ $endpoint | quote }}}
- {name: ARMNET_ARTIFACTS_REGION, value: {{ .region | quote }}}
- name: ARMNET_ARTIFACTS_ACCESS_KEY_ID
  valueFrom: {secretKeyRef: {name: {{ $.secret }}, key: accessKeyId}}
- name: ARMNET_ARTIFACTS_SECRET_ACCESS_KEY
  valueFrom: {secretKeyRef: {name: {{ $.secret }}, key: secretAccessKey}}
{{- end }}
{{- end }}
{{- end -}}
{{- /* The bundled store's identities (templates/object-store.yaml), as a YAML list of
{name, env (the prefix of its variables), secret, actions}: the agent's keys read, list and
write the bucket (SeaweedFS's Write includes delete), the operator's the same (when a Secret
of their own), the FMS's and each tenant reader's only read (a tenant's, only below its
namespace). Each Secret is one identity: the FMS and the tenants never share another's keys. */}}
{{- define "armnet.store.identities" -}}
{{- $a := .Values.artifacts -}}
{{- $b := $a.bucket -}}
{{- if not (regexMatch "^[a-z0-9][a-z0-9.-]{1,61}[a-z0-9]$" $b) -}}
{{- fail (printf "artifacts.bucket %q is not an S3 bucket name (3-63 of a-z, 0-9, '.', '-'; starting and ending with a letter or digit)" $b) -}}
{{- end -}}
{{- $write := list (printf "Read:%s" $b) (printf "List:%s" $b) (printf "Write:%s" $b) -}}
{{- $ids := list (dict "name" "agent" "env" "AGENT" "secret" $a.credentialsSecret "actions" $write) -}}
{{- if and $a.operatorCredentialsSecret (ne $a.operatorCredentialsSecret $a.credentialsSecret) -}}
{{- $ids = append $ids (dict "name" "operator" "env" "OPERATOR" "secret" $a.operatorCredentialsSecret "actions" $write) -}}
{{- end -}}
{{- with $a.fmsCredentialsSecret -}}
{{- $ids = append $ids (dict "name" "fms" "env" "FMS" "secret" . "actions" (list (printf "Read:%s" $b))) -}}
{{- end -}}
{{- range $a.deploy.tenantReaders -}}
{{- $ids = append $ids (dict "name" (printf "tenant-%s" .namespace) "env" (printf "TENANT_%s" (.namespace | upper | replace "-" "_")) "secret" .credentialsSecret "actions" (list (printf "Read:%s/%s/*" $b .namespace))) -}}
{{- end -}}
{{- $names := dict -}}
{{- $secrets := dict -}}
{{- range $ids -}}
{{- if hasKey $names .name -}}
{{- fail (printf "artifacts.deploy.tenantReaders names namespace %s twice" (trimPrefix "tenant-" .name)) -}}
{{- end -}}
{{- if hasKey $secrets .secret -}}
{{- fail (printf "the bundled store's identities %s and %s share the Secret %s: give each its own keys (the FMS's and tenants' read only)" (get $secrets .secret) .name .secret) -}}
{{- end -}}
{{- $_ := set $names .name .secret -}}
{{- $_ := set $secrets .secret .name -}}
{{- end -}}
{{- toYaml $ids -}}
{{- end -}}
{{- /* The bundled store's init script: SeaweedFS's identities file ($S3_CONFIG) from the
Secrets' values in the environment. A key must be one the JSON can hold as is (letters,
digits, + / = . _ ~ -), and no two identities may share an access key; the file appears
whole or not at all. */}}
{{- define "armnet.store.configScript" -}}
{{- $ids := include "armnet.store.identities" . | fromYamlArray -}}
set -eu
umask 077
key() {
  case "$1" in
    "" | *[!A-Za-z0-9+/=._~-]*)
      echo "armnet store: $2 is empty or holds a character other than letters, digits and + / = . _ ~ - (SeaweedFS reads its keys from JSON): put such a key in that Secret" >&2
      exit 1;;
  esac
}
{{- range $ids }}
key "${{ .env }}_ACCESS_KEY_ID" "key accessKeyId of Secret {{ .secret }}"
key "${{ .env }}_SECRET_ACCESS_KEY" "key secretAccessKey of Secret {{ .secret }}"
{{- end }}
shared=$(printf '%s\n' {{ range $ids }}"${{ .env }}_ACCESS_KEY_ID" {{ end }}| sort | uniq -d)
if [ -n "$shared" ]; then
  echo "armnet store: two of the Secrets {{ range $i, $id := $ids }}{{ if $i }}, {{ end }}{{ $id.secret }}{{ end }} hold the same accessKeyId: give each identity keys of its own" >&2
  exit 1
fi
cat > "$S3_CONFIG.partial" <<EOF
{"identities": [
{{- range $i, $id := $ids }}
{{ if $i }},{{ end }}{"name": "{{ $id.name }}", "credentials": [{"accessKey": "${{ $id.env }}_ACCESS_KEY_ID", "secretKey": "${{ $id.env }}_SECRET_ACCESS_KEY"}], "actions": {{ toJson $id.actions }}}
{{- end }}
]}
EOF
mv "$S3_CONFIG.partial" "$S3_CONFIG"
echo "armnet store: {{ len $ids }} identities written to $S3_CONFIG"
{{- end -}}

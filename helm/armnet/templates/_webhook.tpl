{{- /*
The RobotJob admission webhook (docs/operator.md, "Admission webhook"): the operator
serves it over TLS, the API server calls it through a Service. These helpers are what
the operator Deployment includes (env, port, certificate volume) when it is enabled.
*/ -}}

{{- define "armnet.webhook.enabled" -}}
{{- if and .Values.operator.enabled .Values.admissionWebhook.enabled -}}true{{- end -}}
{{- end -}}

{{- define "armnet.webhook.name" -}}{{ include "armnet.fullname" . }}-operator-webhook{{- end -}}

{{/* The Secret with tls.crt/tls.key the operator serves (a pre-created one for source=secret). */}}
{{- define "armnet.webhook.secretName" -}}
{{- $c := .Values.admissionWebhook.certificate -}}
{{- if eq $c.source "secret" -}}
{{- required "admissionWebhook.certificate.secretName: name the pre-created kubernetes.io/tls Secret (source: secret)" $c.secretName -}}
{{- else -}}
{{- default (printf "%s-tls" (include "armnet.webhook.name" .)) $c.secretName -}}
{{- end -}}
{{- end -}}

{{- define "armnet.webhook.mountPath" -}}/etc/armnet/webhook-tls{{- end -}}

{{- define "armnet.webhook.env" -}}
{{- if include "armnet.webhook.enabled" . }}
- {name: ARMNET_OPERATOR_WEBHOOK_PORT, value: {{ .Values.admissionWebhook.port | quote }}}
- {name: ARMNET_OPERATOR_WEBHOOK_ADDRESS, value: "0.0.0.0"}
- {name: ARMNET_OPERATOR_WEBHOOK_CERT_FILE, value: {{ printf "%s/tls.crt" (include "armnet.webhook.mountPath" .) | quote }}}
- {name: ARMNET_OPERATOR_WEBHOOK_KEY_FILE, value: {{ printf "%s/tls.key" (include "armnet.webhook.mountPath" .) | quote }}}
{{- end }}
{{- end -}}

{{- define "armnet.webhook.port" -}}
{{- if include "armnet.webhook.enabled" . }}
- {name: webhook, containerPort: {{ .Values.admissionWebhook.port }}, protocol: TCP}
{{- end }}
{{- end -}}

{{- define "armnet.webhook.volumeMount" -}}
{{- if include "armnet.webhook.enabled" . }}
- {name: webhook-tls, mountPath: {{ include "armnet.webhook.mountPath" . }}, readOnly: true}
{{- end }}
{{- end -}}

{{- define "armnet.webhook.volume" -}}
{{- if include "armnet.webhook.enabled" . }}
- name: webhook-tls
  secret:
    secretName: {{ include "armnet.webhook.secretName" . }}
    defaultMode: 0444
    items:
      - {key: tls.crt, path: tls.crt}
      - {key: tls.key, path: tls.key}
{{- end }}
{{- end -}}

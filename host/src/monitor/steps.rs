//! Turns the run's records into the steps the page shows: the action and its feedback, the
//! policy's words, and the marks drawn on the frame (the hidden truth in simulation, the
//! agent's believed positions). Live runs and replays both go through here.

use serde_json::Value;

use super::view::{Mark, MarkKind, StepView};
use crate::rig::Score;
use crate::run::StepRecord;

/// The step before any action.
pub fn start_step(score: Option<&Score>, frame: Option<usize>) -> StepView {
    StepView {
        evaluation: 0,
        action: None,
        feedback: "start".into(),
        rejected: false,
        frame,
        error: score.and_then(Score::error),
        best_error: score.and_then(Score::error),
        text: None,
        claims: None,
        marks: score.map(true_marks).unwrap_or_default(),
    }
}

/// One recorded step; `frame` is the evaluation whose frame shows its result.
pub fn record_step(record: &StepRecord, frame: Option<usize>) -> StepView {
    let feedback = match &record.rejected {
        Some(reason) => format!("rejected, nothing moved: {reason}"),
        None => format!(
            "executed: motors {:.2} s, camera {:.2} s, agent {:.2} s",
            record.motor_time_s, record.camera_time_s, record.agent_latency_s
        ),
    };
    let mut marks = record.score.as_ref().map(true_marks).unwrap_or_default();
    if let Some(claims) = &record.claims {
        marks.extend(believed_marks(claims));
    }
    StepView {
        evaluation: record.evaluation,
        action: Some(record.action.describe()),
        feedback,
        rejected: record.rejected.is_some(),
        frame,
        error: record.error,
        best_error: record.best_error,
        text: record.claims.as_ref().and_then(model_text),
        claims: record.claims.as_ref().map(shown_claims),
        marks,
    }
}

/// Where the hidden truth puts the beams.
fn true_marks(score: &Score) -> Vec<Mark> {
    let mark = |label: &str, [x, y]: [f64; 2], from_centre| Mark {
        kind: MarkKind::True,
        label: label.to_owned(),
        x,
        y,
        from_centre,
    };
    match score {
        Score::Michelson(score) => vec![
            mark("beam 1", score.beam_centres_px[0], false),
            mark("beam 2", score.beam_centres_px[1], false),
        ],
        Score::Cavity(score) => score
            .secondary_centre_px
            .map(|centre| vec![mark("secondary", centre, false)])
            .unwrap_or_default(),
        Score::Relay(score) => score
            .camera
            .and_then(|view| view.offset_px.map(|offset| (view.station, offset)))
            .map(|(station, offset)| vec![mark(&format!("beam at {station}"), offset, true)])
            .unwrap_or_default(),
    }
}

/// Where the vision agent expects its beams: `mirrors[k].predicted_px` (Michelson) and
/// `secondary.predicted_px` (cavity).
fn believed_marks(claims: &Value) -> Vec<Mark> {
    let mut marks = Vec::new();
    let mut add = |label: String, value: Option<&Value>| {
        if let Some([x, y]) = value.and_then(point) {
            marks.push(Mark {
                kind: MarkKind::Believed,
                label,
                x,
                y,
                from_centre: false,
            });
        }
    };
    if let Some(mirrors) = claims.get("mirrors").and_then(Value::as_array) {
        for (k, mirror) in mirrors.iter().enumerate() {
            add(format!("beam {}", k + 1), mirror.get("predicted_px"));
        }
    }
    add(
        "secondary".into(),
        claims.pointer("/secondary/predicted_px"),
    );
    marks
}

fn point(value: &Value) -> Option<[f64; 2]> {
    match value.as_array()?.as_slice() {
        [x, y] => Some([x.as_f64()?, y.as_f64()?]),
        _ => None,
    }
}

/// The model's last reply text, for a VLM decision.
fn model_text(claims: &Value) -> Option<String> {
    claims
        .get("exchanges")?
        .as_array()?
        .last()?
        .pointer("/completion/text")?
        .as_str()
        .map(str::to_owned)
}

/// The claims worth showing: a VLM's structured reply without the recorded exchanges (its
/// text is shown on its own), or a vision agent's beliefs whole.
fn shown_claims(claims: &Value) -> Value {
    match claims.get("agent") {
        Some(agent) if claims.get("exchanges").is_some() => agent.clone(),
        _ => claims.clone(),
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;
    use crate::policy::Decision;
    use crate::task::Action;
    use crate::task::michelson::MichelsonScore;

    fn michelson_record(claims: Option<Value>, rejected: Option<&str>) -> StepRecord {
        let mut decision = Decision::new(Action::Michelson {
            command: [10, 0, 0, -5],
            done: false,
        });
        decision.claims = claims;
        match rejected {
            Some(reason) => StepRecord::rejected(3, &decision, reason),
            None => StepRecord {
                score: Some(Score::Michelson(MichelsonScore {
                    error_px: 12.0,
                    commanded_error_px: 11.0,
                    beam_centres_px: [[100.0, 90.0], [130.0, 95.0]],
                })),
                error: Some(12.0),
                ..StepRecord::rejected(3, &decision, "")
            },
        }
    }

    #[test]
    fn a_vision_step_marks_the_truth_and_the_beliefs() {
        let claims = json!({
            "phase": "probe mirror 1",
            "mirrors": [{"predicted_px": [101.0, 89.5]}, {"predicted_px": null}],
        });
        let mut record = michelson_record(Some(claims.clone()), None);
        record.rejected = None;
        let step = record_step(&record, Some(3));
        let kinds: Vec<(MarkKind, &str)> = step
            .marks
            .iter()
            .map(|m| (m.kind, m.label.as_str()))
            .collect();
        assert_eq!(
            kinds,
            [
                (MarkKind::True, "beam 1"),
                (MarkKind::True, "beam 2"),
                (MarkKind::Believed, "beam 1"),
            ]
        );
        assert_eq!((step.marks[2].x, step.marks[2].y), (101.0, 89.5));
        assert_eq!(step.claims, Some(claims));
        assert!(step.feedback.starts_with("executed"), "{}", step.feedback);
        assert_eq!(step.error, Some(12.0));
    }

    #[test]
    fn a_vlm_step_shows_its_reply_text_and_structured_claims() {
        let claims = json!({
            "agent": {"beam_1": "left of centre"},
            "exchanges": [
                {"completion": {"text": "first try"}},
                {"completion": {"text": "I move mirror 1 left."}},
            ],
        });
        let step = record_step(&michelson_record(Some(claims), Some("out of range")), None);
        assert_eq!(step.text.as_deref(), Some("I move mirror 1 left."));
        assert_eq!(step.claims, Some(json!({"beam_1": "left of centre"})));
        assert!(step.rejected);
        assert_eq!(step.feedback, "rejected, nothing moved: out of range");
        assert!(step.marks.is_empty());
    }
}

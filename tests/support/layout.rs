//! A Foxglove layout checked against a recording: every topic a panel shows is in the
//! recording, and every plotted field is a number in the topic's last message, so that no
//! panel of a shipped layout is empty for want of a misspelled name.

use std::collections::BTreeMap;
use std::path::Path;

/// `layout` (a Foxglove layout file) names only what the MCAP `recording` holds.
pub fn names_only_what_the_recording_has(layout: &Path, recording: &[u8]) {
    let mut last: BTreeMap<String, Vec<u8>> = BTreeMap::new();
    for message in mcap::MessageStream::new(recording).expect("an MCAP") {
        let message = message.expect("a complete message");
        last.insert(message.channel.topic.clone(), message.data.to_vec());
    }
    let text = std::fs::read_to_string(layout).unwrap_or_else(|e| panic!("{}: {e}", layout.display()));
    let parsed: serde_json::Value = serde_json::from_str(&text).expect("the layout is JSON");
    let panels = parsed["configById"].as_object().expect("configById");
    let mut topics: Vec<String> = Vec::new();
    let mut fields: Vec<String> = Vec::new();
    for (id, config) in panels {
        // Foxglove reads a panel's title from `foxglovePanelTitle` (only Plot still converts an
        // old `title`): every panel is named the one way.
        assert!(config["foxglovePanelTitle"].is_string() && config.get("title").is_none(), "{id} has no foxglovePanelTitle");
        topics.extend(config["topics"].as_object().into_iter().flat_map(|t| t.keys().cloned()));
        topics.extend([&config["imageMode"]["imageTopic"], &config["imageMode"]["calibrationTopic"], &config["topicToRender"]].into_iter().filter_map(|v| v.as_str().map(str::to_owned)));
        fields.extend(config["paths"].as_array().into_iter().flatten().filter_map(|p| p["value"].as_str().map(str::to_owned)));
    }
    assert!(topics.len() >= 3 && fields.len() >= 8, "{}: {topics:?} {fields:?}", layout.display());
    for topic in &topics {
        assert!(last.contains_key(topic), "{} shows {topic}, which the recording does not have", layout.display());
    }
    for field in &fields {
        let (topic, path) = field.split_once('.').expect("topic.field");
        let message: serde_json::Value = serde_json::from_slice(last.get(topic).unwrap_or_else(|| panic!("{} plots {field}: no {topic}", layout.display()))).expect("JSON");
        let value = path.split('.').fold(&message, |v, key| &v[key]);
        assert!(value.is_number(), "{} plots {field}, not in {topic}'s messages: {message}", layout.display());
    }
    // Each panel in the arrangement is configured, and each configured panel is placed.
    let placed = text.matches("\"first\": \"").count() + text.matches("\"second\": \"").count();
    assert_eq!(placed, panels.len(), "{}: panels placed in the layout tree", layout.display());
}

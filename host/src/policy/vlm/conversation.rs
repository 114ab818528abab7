//! The conversation with the model: the system prompt, then every observation (text and
//! image), every reply and every corrective message, in order, as the paper keeps it. When a
//! model's context is small, only the newest N images are sent; older ones are replaced by a
//! short note, while all text (the model's own notes about those images) stays.

use serde_json::{Value, json};

use super::image::PreparedImage;

/// What stands in for an image that is no longer sent.
pub const OMITTED_IMAGE: &str =
    "[This image is no longer attached, to save context; rely on what you wrote about it.]";

enum Message {
    User {
        text: String,
        image: Option<PreparedImage>,
    },
    Assistant(String),
}

/// The whole exchange so far.
pub struct Conversation {
    system: String,
    messages: Vec<Message>,
    keep_images: Option<usize>,
}

impl Conversation {
    /// Starts with the system prompt; `keep_images` limits how many of the newest images are
    /// sent (`None` = all).
    pub fn new(system: String, keep_images: Option<usize>) -> Self {
        Self {
            system,
            messages: Vec::new(),
            keep_images,
        }
    }

    pub fn system(&self) -> &str {
        &self.system
    }

    pub fn push_user(&mut self, text: String, image: Option<PreparedImage>) {
        self.messages.push(Message::User { text, image });
    }

    pub fn push_assistant(&mut self, text: &str) {
        // Some providers refuse an empty assistant turn.
        let text = if text.trim().is_empty() {
            "(empty reply)"
        } else {
            text
        };
        self.messages.push(Message::Assistant(text.to_owned()));
    }

    /// The text of the newest user message.
    pub fn last_user_text(&self) -> Option<&str> {
        self.messages
            .iter()
            .rev()
            .find_map(|message| match message {
                Message::User { text, .. } => Some(text.as_str()),
                Message::Assistant(_) => None,
            })
    }

    fn image_count(&self) -> usize {
        self.messages
            .iter()
            .filter(|m| matches!(m, Message::User { image: Some(_), .. }))
            .count()
    }

    /// How many images the next request carries, and how many were left out.
    pub fn image_counts(&self) -> (usize, usize) {
        let total = self.image_count();
        let sent = self.keep_images.map_or(total, |keep| total.min(keep));
        (sent, total - sent)
    }

    /// The chat-completions `messages` array.
    pub fn messages(&self) -> Vec<Value> {
        let (_, omitted) = self.image_counts();
        let mut seen = 0usize;
        let mut out = Vec::with_capacity(self.messages.len() + 1);
        out.push(json!({ "role": "system", "content": self.system }));
        for message in &self.messages {
            out.push(match message {
                Message::Assistant(text) => json!({ "role": "assistant", "content": text }),
                Message::User { text, image: None } => json!({ "role": "user", "content": text }),
                Message::User {
                    text,
                    image: Some(image),
                } => {
                    seen += 1;
                    let attachment = if seen > omitted {
                        json!({ "type": "image_url", "image_url": { "url": image.data_url } })
                    } else {
                        json!({ "type": "text", "text": OMITTED_IMAGE })
                    };
                    json!({
                        "role": "user",
                        "content": [{ "type": "text", "text": text }, attachment],
                    })
                }
            });
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(n: u32) -> PreparedImage {
        PreparedImage {
            data_url: format!("data:image/png;base64,{n}"),
            width: n,
            height: n,
        }
    }

    fn image_urls(messages: &[Value]) -> Vec<String> {
        messages
            .iter()
            .filter_map(|m| m["content"].as_array())
            .flatten()
            .filter_map(|part| part["image_url"]["url"].as_str().map(str::to_owned))
            .collect()
    }

    #[test]
    fn keeps_everything_in_order_by_default() {
        let mut conversation = Conversation::new("sys".into(), None);
        conversation.push_user("Image 0".into(), Some(image(1)));
        conversation.push_assistant("reply 1");
        conversation.push_user("fix it".into(), None);
        conversation.push_assistant("");
        let messages = conversation.messages();
        let roles: Vec<&str> = messages
            .iter()
            .map(|m| m["role"].as_str().unwrap())
            .collect();
        assert_eq!(roles, ["system", "user", "assistant", "user", "assistant"]);
        assert_eq!(messages[0]["content"], "sys");
        assert_eq!(messages[1]["content"][0]["text"], "Image 0");
        assert_eq!(messages[3]["content"], "fix it");
        assert_eq!(messages[4]["content"], "(empty reply)");
        assert_eq!(image_urls(&messages).len(), 1);
        assert_eq!(conversation.last_user_text(), Some("fix it"));
    }

    #[test]
    fn sends_only_the_newest_images_when_asked() {
        let mut conversation = Conversation::new("sys".into(), Some(2));
        for n in 0..4 {
            conversation.push_user(format!("Image {n}"), Some(image(n)));
            conversation.push_assistant("ok");
        }
        assert_eq!(conversation.image_counts(), (2, 2));
        let messages = conversation.messages();
        assert_eq!(
            image_urls(&messages),
            ["data:image/png;base64,2", "data:image/png;base64,3"]
        );
        assert_eq!(messages[1]["content"][1]["text"], OMITTED_IMAGE);
        assert_eq!(messages[1]["content"][0]["text"], "Image 0");
    }
}

//! Toasts: the studio's errors and messages, stacked in the bottom-right corner of the main
//! panel.
//!
//! Errors stay until dismissed, so nothing a user must read disappears on its own, and a
//! second error does not replace the first; messages (a save, an export, a finished job)
//! fade after [`MESSAGE_SECONDS`]. A notice that is already shown is counted, not stacked
//! again: a view that cannot draw reports the same error on every frame.

/// What a notice is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoticeKind {
    Error,
    Message,
}

/// One toast.
#[derive(Clone, Debug, PartialEq)]
pub struct Notice {
    pub kind: NoticeKind,
    pub text: String,
    /// How many more times the same notice was posted while it was shown.
    pub repeats: u32,
    /// The egui time it was (last) posted at; set when it is first drawn.
    posted_at: Option<f64>,
}

/// How long a message stays, seconds.
pub const MESSAGE_SECONDS: f64 = 6.0;

/// At most this many toasts are drawn; the rest are summarised in one line.
pub const MAX_SHOWN: usize = 4;

/// The studio's notices, oldest first.
#[derive(Clone, Debug, Default)]
pub struct Notices {
    list: Vec<Notice>,
}

impl Notices {
    /// Posts an error (kept until dismissed).
    pub fn error(&mut self, text: impl Into<String>) {
        self.post(NoticeKind::Error, text.into());
    }

    /// Posts a message (fades after [`MESSAGE_SECONDS`]).
    pub fn message(&mut self, text: impl Into<String>) {
        self.post(NoticeKind::Message, text.into());
    }

    fn post(&mut self, kind: NoticeKind, text: String) {
        if let Some(k) = self
            .list
            .iter()
            .position(|n| n.kind == kind && n.text == text)
        {
            // A repeat moves to the front of the stack and restarts its time.
            let mut notice = self.list.remove(k);
            notice.repeats += 1;
            notice.posted_at = None;
            self.list.push(notice);
        } else {
            self.list.push(Notice {
                kind,
                text,
                repeats: 0,
                posted_at: None,
            });
        }
    }

    /// All notices shown now, oldest first.
    pub fn all(&self) -> &[Notice] {
        &self.list
    }

    /// The errors not yet dismissed, oldest first.
    pub fn errors(&self) -> impl Iterator<Item = &str> {
        self.of_kind(NoticeKind::Error)
    }

    /// The most recent error not yet dismissed.
    pub fn latest_error(&self) -> Option<&str> {
        self.errors().last()
    }

    /// The most recent message still shown.
    pub fn latest_message(&self) -> Option<&str> {
        self.of_kind(NoticeKind::Message).last()
    }

    fn of_kind(&self, kind: NoticeKind) -> impl Iterator<Item = &str> {
        self.list
            .iter()
            .filter(move |n| n.kind == kind)
            .map(|n| n.text.as_str())
    }

    /// Removes the notice at `index` of [`Notices::all`].
    pub fn dismiss(&mut self, index: usize) {
        if index < self.list.len() {
            self.list.remove(index);
        }
    }

    /// Removes every notice.
    pub fn dismiss_all(&mut self) {
        self.list.clear();
    }

    /// Stamps new notices with `now` and drops messages older than [`MESSAGE_SECONDS`];
    /// returns how long until the next message expires (the UI repaints then).
    pub fn expire(&mut self, now: f64) -> Option<f64> {
        for notice in &mut self.list {
            notice.posted_at.get_or_insert(now);
        }
        self.list.retain(|n| {
            n.kind == NoticeKind::Error || n.posted_at.is_some_and(|t| now - t < MESSAGE_SECONDS)
        });
        self.list
            .iter()
            .filter(|n| n.kind == NoticeKind::Message)
            .filter_map(|n| n.posted_at)
            .map(|t| MESSAGE_SECONDS - (now - t))
            .reduce(f64::min)
    }

    /// Draws the toasts, newest at the bottom, anchored to the bottom-right corner of
    /// `within` (the main panel).
    pub fn ui(&mut self, ctx: &egui::Context, within: egui::Rect) {
        let now = ctx.input(|i| i.time);
        if let Some(seconds) = self.expire(now) {
            ctx.request_repaint_after(std::time::Duration::from_secs_f64(seconds.max(0.0)));
        }
        if self.list.is_empty() {
            return;
        }
        let hidden = self.list.len().saturating_sub(MAX_SHOWN);
        let mut dismissed = None;
        let mut dismiss_all = false;
        egui::Area::new(egui::Id::unique("notices"))
            .order(egui::Order::Foreground)
            .pivot(egui::Align2::RIGHT_BOTTOM)
            .fixed_pos(within.right_bottom() - egui::vec2(12.0, 12.0))
            .show(ctx, |ui| {
                ui.set_max_width(within.width().clamp(160.0, 460.0));
                if hidden > 0 {
                    ui.horizontal(|ui| {
                        ui.label(format!("{hidden} earlier notices"));
                        if ui.button("Dismiss all").clicked() {
                            dismiss_all = true;
                        }
                    });
                }
                for (k, notice) in self.list.iter().enumerate().skip(hidden) {
                    if toast_ui(ui, notice) {
                        dismissed = Some(k);
                    }
                }
            });
        if dismiss_all {
            self.dismiss_all();
        } else if let Some(k) = dismissed {
            self.dismiss(k);
        }
    }
}

/// One toast; true when its Dismiss button was clicked.
fn toast_ui(ui: &mut egui::Ui, notice: &Notice) -> bool {
    let (accent, title) = match notice.kind {
        NoticeKind::Error => (egui::Color32::from_rgb(230, 90, 80), "Error"),
        NoticeKind::Message => (egui::Color32::from_rgb(90, 170, 110), "Done"),
    };
    let mut dismissed = false;
    egui::Frame::popup(ui.style())
        .stroke(egui::Stroke::new(1.0, accent))
        .show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.colored_label(accent, title);
                if notice.repeats > 0 {
                    ui.weak(format!("x{}", notice.repeats + 1));
                }
                ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
                    dismissed = ui.small_button("Dismiss").clicked();
                    if ui
                        .small_button("Copy")
                        .on_hover_text("Copy the text")
                        .clicked()
                    {
                        ui.ctx().copy_text(notice.text.clone());
                    }
                });
            });
            ui.add(egui::Label::new(&notice.text).wrap());
        });
    dismissed
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_stay_messages_fade_and_repeats_are_counted() {
        let mut notices = Notices::default();
        notices.error("first");
        notices.message("saved");
        notices.error("second");
        notices.error("first");
        assert_eq!(notices.errors().collect::<Vec<_>>(), ["second", "first"]);
        assert_eq!(notices.all()[2].repeats, 1, "the repeat is counted");
        assert_eq!(notices.latest_error(), Some("first"));

        // Shown at t = 10 s: the message expires MESSAGE_SECONDS later, the errors never.
        let until = notices.expire(10.0).expect("a message is shown");
        assert!((until - MESSAGE_SECONDS).abs() < 1e-9);
        assert_eq!(notices.latest_message(), Some("saved"));
        assert_eq!(
            notices.expire(10.0 + MESSAGE_SECONDS - 0.1).map(f64::round),
            Some(0.0)
        );
        assert_eq!(notices.expire(10.0 + MESSAGE_SECONDS + 0.1), None);
        assert_eq!(notices.latest_message(), None);
        assert_eq!(notices.expire(1e6), None);
        assert_eq!(notices.errors().count(), 2);

        // A message posted again restarts its time.
        notices.message("exported");
        notices.expire(100.0);
        notices.message("exported");
        notices.expire(104.0);
        assert_eq!(notices.expire(108.0).map(f64::round), Some(2.0));

        notices.dismiss(0);
        assert_eq!(notices.latest_error(), Some("first"));
        assert_eq!(notices.errors().count(), 1);
        notices.dismiss(99);
        notices.dismiss_all();
        assert!(notices.all().is_empty());
    }
}

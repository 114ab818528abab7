//! Who gets a network slot: admission and eviction of connections, without I/O.
//!
//! A controller serves a fixed number of network connections with full rights ("slots")
//! and keeps a small lobby beside them. Only a connection that speaks can take a slot from
//! someone else, so connections that stay silent cannot keep out a client with the key,
//! however often they reconnect:
//!
//! - a newcomer takes a free slot; when none is free it waits in the lobby, where it may
//!   shake hands and send `EmergencyStop` and nothing else; when the lobby is full it
//!   replaces the oldest lobby connection that has not sent a well-formed request yet, and
//!   is refused (closed at once) only when every lobby connection has spoken;
//! - a lobby connection that sends a well-formed request is promoted to a slot: a free one,
//!   or one it takes by evicting an unauthenticated connection, the least advanced first
//!   (silent before spoken), the oldest first. A silent connection younger than
//!   [`SILENT_GRACE_US`], or one that spoke and is younger than [`AUTH_GRACE_US`], is not
//!   evicted: a client has that long to say something and to authenticate. Authenticated
//!   connections are never evicted. When nobody can be evicted it stays in the lobby;
//! - the embedder closes the connection whose token an admission or a promotion hands
//!   back, tells the table how each connection stands ([`Admissions::standing`]) and
//!   releases each ticket when its connection ends.

/// Lobby places beside the slots, on boards and the simulated peer alike.
pub const LOBBY: usize = 1;

/// Slots a table can hold at most.
pub const MAX_SLOTS: usize = 16;

/// Lobby places a table can hold at most.
pub const MAX_LOBBY: usize = 4;

/// How long a connection in a slot may stay silent before a newcomer can evict it.
pub const SILENT_GRACE_US: u64 = 100_000;

/// How long a connection that spoke may take to authenticate before it can be evicted.
pub const AUTH_GRACE_US: u64 = 1_000_000;

/// How far a connection has come, least first: eviction takes the least advanced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Standing {
    /// No well-formed request yet.
    Silent,
    /// At least one well-formed request, not authenticated.
    Spoke,
    /// Authenticated: never evicted.
    Authenticated,
}

/// A connection's place: a network slot or lobby place, or the serial link (which needs
/// none).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ticket {
    Serial,
    Network { index: u8, generation: u32 },
}

/// What becomes of a new connection.
#[derive(Debug, PartialEq, Eq)]
pub enum Admission<T> {
    /// A free slot.
    Slot(Ticket),
    /// A lobby place (handshake and emergency stops only until promoted), which may have
    /// been taken from the silent connection whose token is given.
    Lobby { ticket: Ticket, evicted: Option<T> },
    /// No room: close it at once.
    Refused,
}

/// A slot for a lobby connection, possibly freed by evicting the connection whose token is
/// given.
#[derive(Debug, PartialEq, Eq)]
pub struct Promotion<T> {
    pub ticket: Ticket,
    pub evicted: Option<T>,
}

#[derive(Debug)]
struct Entry<T> {
    generation: u32,
    opened_us: u64,
    standing: Standing,
    token: T,
}

/// The slots and the lobby of one controller; `T` is what the embedder needs to close a
/// connection it is told to evict.
#[derive(Debug)]
pub struct Admissions<T> {
    /// Slots first, the lobby from [`MAX_SLOTS`] on.
    entries: [Option<Entry<T>>; MAX_SLOTS + MAX_LOBBY],
    slots: usize,
    lobby: usize,
    generation: u32,
}

impl<T> Admissions<T> {
    /// `slots` network slots (1..=[`MAX_SLOTS`]) and `lobby` places beside them
    /// (..=[`MAX_LOBBY`]), clamped.
    pub const fn new(slots: usize, lobby: usize) -> Self {
        Self {
            entries: [const { None }; MAX_SLOTS + MAX_LOBBY],
            slots: clamp(slots, 1, MAX_SLOTS),
            lobby: clamp(lobby, 0, MAX_LOBBY),
            generation: 0,
        }
    }

    /// Admits a connection accepted at `now_us`; `token` identifies it to the embedder.
    pub fn admit(&mut self, now_us: u64, token: T) -> Admission<T> {
        if let Some(index) = self.free(0..self.slots) {
            return Admission::Slot(self.place(index, now_us, token).0);
        }
        let lobby = MAX_SLOTS..MAX_SLOTS + self.lobby;
        let index = self.free(lobby.clone()).or_else(|| {
            self.indexed(lobby)
                .filter(|(_, entry)| entry.standing == Standing::Silent)
                .min_by_key(|(_, entry)| entry.opened_us)
                .map(|(index, _)| index)
        });
        match index {
            Some(index) => {
                let (ticket, evicted) = self.place(index, now_us, token);
                Admission::Lobby { ticket, evicted }
            }
            None => Admission::Refused,
        }
    }

    /// Moves the lobby connection holding `ticket`, which has just sent a well-formed
    /// request, into a slot if one is free or can be freed at `now_us`; `None` when it
    /// stays in the lobby (or does not hold a lobby place).
    pub fn promote(&mut self, ticket: Ticket, now_us: u64) -> Option<Promotion<T>> {
        let Ticket::Network { index, .. } = ticket else {
            return None;
        };
        let from = usize::from(index);
        if from < MAX_SLOTS || self.entry(ticket).is_none() {
            return None;
        }
        let to = self.free(0..self.slots).or_else(|| {
            self.indexed(0..self.slots)
                .filter(|(_, entry)| evictable(entry, now_us))
                .min_by_key(|(_, entry)| (entry.standing, entry.opened_us))
                .map(|(index, _)| index)
        })?;
        let mut moving = self.entries.get_mut(from)?.take()?;
        // The grace for authenticating runs from the promotion.
        moving.opened_us = now_us;
        moving.standing = moving.standing.max(Standing::Spoke);
        let generation = moving.generation;
        let evicted = self.entries.get_mut(to)?.replace(moving);
        Some(Promotion {
            ticket: Ticket::Network {
                index: u8::try_from(to).ok()?,
                generation,
            },
            evicted: evicted.map(|entry| entry.token),
        })
    }

    /// Notes how the connection holding `ticket` stands now.
    pub fn standing(&mut self, ticket: Ticket, standing: Standing) {
        if let Some(entry) = self.entry(ticket) {
            entry.standing = standing;
        }
    }

    /// Frees the place of a connection that ended (nothing if it was evicted meanwhile).
    pub fn release(&mut self, ticket: Ticket) {
        if self.entry(ticket).is_some()
            && let Ticket::Network { index, .. } = ticket
            && let Some(place) = self.entries.get_mut(usize::from(index))
        {
            *place = None;
        }
    }

    /// Network connections open now, in slots and in the lobby.
    pub fn open(&self) -> usize {
        self.entries.iter().flatten().count()
    }

    /// Whether `ticket` is a lobby place.
    pub fn in_lobby(ticket: Ticket) -> bool {
        matches!(ticket, Ticket::Network { index, .. } if usize::from(index) >= MAX_SLOTS)
    }

    fn free(&self, range: core::ops::Range<usize>) -> Option<usize> {
        let start = range.start;
        let places = self.entries.get(range)?;
        places.iter().position(Option::is_none).map(|i| start + i)
    }

    fn indexed(
        &self,
        range: core::ops::Range<usize>,
    ) -> impl Iterator<Item = (usize, &Entry<T>)> + '_ {
        let start = range.start;
        self.entries
            .get(range)
            .unwrap_or_default()
            .iter()
            .enumerate()
            .filter_map(move |(i, entry)| Some((start + i, entry.as_ref()?)))
    }

    /// Puts a new connection at `index`; its ticket, and the token of the one it replaced.
    fn place(&mut self, index: usize, now_us: u64, token: T) -> (Ticket, Option<T>) {
        self.generation = self.generation.wrapping_add(1);
        let generation = self.generation;
        let replaced = self.entries.get_mut(index).and_then(|place| {
            place.replace(Entry {
                generation,
                opened_us: now_us,
                standing: Standing::Silent,
                token,
            })
        });
        let ticket = Ticket::Network {
            index: u8::try_from(index).unwrap_or(u8::MAX),
            generation,
        };
        (ticket, replaced.map(|entry| entry.token))
    }

    fn entry(&mut self, ticket: Ticket) -> Option<&mut Entry<T>> {
        let Ticket::Network { index, generation } = ticket else {
            return None;
        };
        self.entries
            .get_mut(usize::from(index))?
            .as_mut()
            .filter(|entry| entry.generation == generation)
    }
}

/// Whether a connection in a slot may be evicted at `now_us`.
fn evictable<T>(entry: &Entry<T>, now_us: u64) -> bool {
    let grace = match entry.standing {
        Standing::Silent => SILENT_GRACE_US,
        Standing::Spoke => AUTH_GRACE_US,
        Standing::Authenticated => return false,
    };
    now_us.saturating_sub(entry.opened_us) >= grace
}

const fn clamp(value: usize, min: usize, max: usize) -> usize {
    if value < min {
        min
    } else if value > max {
        max
    } else {
        value
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slot(admission: Admission<u32>) -> Ticket {
        match admission {
            Admission::Slot(ticket) => ticket,
            other => panic!("no slot: {other:?}"),
        }
    }

    fn lobby(admission: Admission<u32>) -> (Ticket, Option<u32>) {
        match admission {
            Admission::Lobby { ticket, evicted } => (ticket, evicted),
            other => panic!("not in the lobby: {other:?}"),
        }
    }

    #[test]
    fn silent_newcomers_wait_in_the_lobby_and_replace_each_other_there_only() {
        let mut table = Admissions::new(2, 1);
        slot(table.admit(0, 1));
        slot(table.admit(0, 2));
        // However many silent newcomers come, long after: nobody in a slot is evicted.
        let (first, evicted) = lobby(table.admit(10_000_000, 3));
        assert_eq!(evicted, None);
        let (_, evicted) = lobby(table.admit(10_000_001, 4));
        assert_eq!(evicted, Some(3), "the silent lobby connection makes room");
        assert_eq!(
            table.promote(first, 10_000_002),
            None,
            "evicted: no promotion"
        );
        assert_eq!(table.open(), 3);
    }

    #[test]
    fn a_lobby_connection_that_speaks_takes_the_slot_of_the_least_advanced_stranger() {
        let mut table = Admissions::new(3, 1);
        let silent = slot(table.admit(0, 1));
        let spoke = slot(table.admit(10, 2));
        let keyed = slot(table.admit(20, 3));
        table.standing(spoke, Standing::Spoke);
        table.standing(keyed, Standing::Authenticated);

        // Everyone within their grace: the speaker stays in the lobby.
        let (waiting, _) = lobby(table.admit(100, 4));
        assert!(Admissions::<u32>::in_lobby(waiting));
        assert_eq!(table.promote(waiting, 100), None);
        // Past the silent grace: the silent one goes, though the other is older.
        let promoted = table.promote(waiting, SILENT_GRACE_US).unwrap();
        assert_eq!(promoted.evicted, Some(1));
        assert!(!Admissions::<u32>::in_lobby(promoted.ticket));
        // The evicted connection's own release frees nothing; the old lobby ticket is gone.
        table.release(silent);
        table.release(waiting);
        assert_eq!(table.open(), 3);
        table.standing(promoted.ticket, Standing::Authenticated);

        // The one that spoke goes once past its grace, never an authenticated one.
        let (next, _) = lobby(table.admit(AUTH_GRACE_US / 2, 5));
        table.standing(next, Standing::Spoke);
        assert_eq!(table.promote(next, AUTH_GRACE_US - 1), None);
        let promoted = table.promote(next, AUTH_GRACE_US + 10).unwrap();
        assert_eq!(promoted.evicted, Some(2));
        table.standing(promoted.ticket, Standing::Authenticated);

        // Every slot authenticated: a speaker stays in the lobby, and the lobby, held by
        // one that spoke, refuses the next newcomer.
        let (last, _) = lobby(table.admit(u64::MAX / 2, 6));
        table.standing(last, Standing::Spoke);
        assert_eq!(table.promote(last, u64::MAX), None);
        assert_eq!(table.admit(u64::MAX, 7), Admission::Refused);
        // A key holder leaving frees a slot for it.
        table.release(keyed);
        assert_eq!(table.promote(last, u64::MAX).unwrap().evicted, None);
    }

    #[test]
    fn sizes_are_clamped() {
        let mut table = Admissions::<u32>::new(0, 0);
        slot(table.admit(0, 1));
        assert_eq!(table.admit(0, 2), Admission::Refused);
        let table = Admissions::<u32>::new(1000, 1000);
        assert_eq!((table.slots, table.lobby), (MAX_SLOTS, MAX_LOBBY));
    }
}

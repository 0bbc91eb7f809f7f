//! The sled trees the writer writes, held together so that a rollback
//! record can name one ([`TreeName`]) and get it back.

use crate::rollback::TreeName;

/// The trees the writer writes.
pub(crate) struct Trees {
    pub db: sled::Db,
    pub keyframes: sled::Tree,
    pub meta: sled::Tree,
    pub journal: sled::Tree,
    pub verdicts: sled::Tree,
    pub verdicts_by_candidate: sled::Tree,
}

impl Trees {
    /// The tree a rollback record names.
    pub(super) fn named(&self, name: TreeName) -> &sled::Tree {
        match name {
            TreeName::Keyframes => &self.keyframes,
            TreeName::Journal => &self.journal,
            TreeName::Meta => &self.meta,
            TreeName::Verdicts => &self.verdicts,
            TreeName::VerdictsByCandidate => &self.verdicts_by_candidate,
        }
    }
}

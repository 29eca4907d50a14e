//! Check: re-measure a tileset from its files (see verify).

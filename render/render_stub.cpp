namespace s2r {}

// Links one library's whole archive with its declared links only (see CMakeLists.txt).
int main() { return 0; }

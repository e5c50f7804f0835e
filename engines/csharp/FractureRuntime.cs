// FractureRuntime.cs - reader of the `fracture` impact-projection file, one file, no dependencies.
//
// C# 7.2 subset, so it builds with Unity (.NET Standard 2.1 / C# 8 and later), .NET and Mono's mcs.
// Loads `<stem>.fracture.json` + `<stem>.fracture.bin` from bytes, validates them, and answers
// "which fragments break off" for a hit without allocating. Specification: docs/FORMAT.md of the
// fracture repository (format version 1, and version 2 with the features "stress": the stress criterion
// of section 11, "anchors" and "damage": structures and damage that adds up over hits, section 12, with
// the optional crack arrays, and "levels": fragments that break again, section 14).
//
// MIT licence, Copyright (c) fracture developers (see LICENSE next to this file).
//
//   var runtime = FractureRuntime.Load(File.ReadAllBytes(jsonPath), File.ReadAllBytes(binPath));
//   var impact = new FractureImpact(runtime);          // reusable result + scratch, one per thread
//   runtime.Project(px, py, pz, nx, ny, nz, runtime.DefaultThreshold, impact);
//   // fragments j with equal impact.Groups[j] move together; impact.Groups[j] == j starts a group
//
// With damage that adds up (section 12), keep one state per object and hit it instead:
//
//   double[] health = runtime.NewState();              // one per object: e bond healths, all 1
//   runtime.Hit(health, px, py, pz, nx, ny, nz, runtime.DefaultThreshold, impact);

using System;
using System.Collections.Generic;
using System.Globalization;
using System.Runtime.InteropServices;
using System.Text;

namespace Fracture
{
    /// <summary>Why a file did not load or an impact was refused.</summary>
    public enum FractureStatus
    {
        Ok = 0,
        Argument,  // a null argument or an impact object of another runtime
        Json,      // the header is not valid JSON (or not UTF-8)
        Format,    // not a fracture runtime file, or a version this reader does not know
        Header,    // a header entry is missing or has the wrong type or value
        Size,      // binary size, array sizes, offsets or shapes disagree
        Crc,       // the binary's CRC-32 differs from the header's
        Data,      // a non-finite value or an edge index out of range in the binary
        Input,     // Project, Hit: non-finite point or impulse, NaN or negative threshold
        State,     // Hit and the state methods: a damage state that is not e values in [0, 1]
        Fragment,  // HitPiece: the struck fragment is not shown (split, or inside an unbroken parent)
    }

    /// <summary>A runtime file that cannot be used; <see cref="Status"/> says which check failed.</summary>
    public sealed class FractureRuntimeException : Exception
    {
        public readonly FractureStatus Status;

        public FractureRuntimeException(FractureStatus status, string message) : base(message)
        {
            Status = status;
        }
    }

    /// <summary>
    /// Result arrays and scratch memory of <see cref="FractureRuntime.Project"/>: allocate one per
    /// runtime and thread, reuse it for every hit (Project itself never allocates).
    /// </summary>
    public sealed class FractureImpact
    {
        /// <summary>[p] group of each fragment: the smallest fragment index in it.</summary>
        public readonly int[] Groups;
        /// <summary>[e] whether each edge broke.</summary>
        public readonly bool[] Broken;
        /// <summary>[k] mode coefficients.</summary>
        public readonly double[] Alpha;
        /// <summary>[p * d] fragment displacements, row-major, model axes (dimensionless).</summary>
        public readonly double[] Displacement;
        /// <summary>[e] whether each bond holds but is cracked (all false from Project without feature "damage").</summary>
        public readonly bool[] Cracked;
        /// <summary>[p] whether each fragment's group holds a fragment bonded to the world (keep it static).</summary>
        public readonly bool[] Anchored;
        public int Site, NumGroups, NumBroken, NumCracked;
        /// <summary>Fill <see cref="Displacement"/> (k*p*d multiply-adds; the groups do not need them).</summary>
        public bool ComputeDisplacement = true;

        internal readonly FractureRuntime Owner;
        internal readonly double[] ScaledAlpha, ScaledDisp;
        internal readonly int[] Labels; // [2p] union-find parents, or the merge labels of the jump table
        internal readonly double[] FreshHealth; // [e] Project's damage state on a file with feature "damage"
        internal readonly byte[] Cut;           // [e] Hit: the bonds this hit cracks
        internal readonly int[] KdIds = new int[FractureRuntime.KdStack];
        internal readonly double[] KdBounds = new double[FractureRuntime.KdStack];

        public FractureImpact(FractureRuntime runtime)
        {
            if (runtime == null)
                throw new ArgumentNullException("runtime");
            Owner = runtime;
            Groups = new int[runtime.Fragments];
            Broken = new bool[runtime.Edges];
            Alpha = new double[runtime.Modes];
            Displacement = new double[runtime.Fragments * runtime.Dim];
            ScaledAlpha = new double[runtime.Modes];
            ScaledDisp = new double[runtime.Fragments * runtime.Dim];
            Labels = new int[2 * runtime.Fragments];
            Cracked = new bool[runtime.Edges];
            Anchored = new bool[runtime.Fragments];
            FreshHealth = new double[runtime.Edges];
            Cut = new byte[runtime.Edges];
        }
    }

    /// <summary>Sibling fragments that move together (docs/FORMAT.md section 14.4): one rigid body in the game.</summary>
    public sealed class FracturePiece
    {
        /// <summary>The body whose children they are (0: level-1 fragments).</summary>
        public readonly int Body;
        /// <summary>Global fragment indices, ascending.</summary>
        public readonly List<int> Fragments = new List<int>();
        /// <summary>Whether the piece holds a fragment bonded to the world (level 1 only: keep it static).</summary>
        public bool Anchored;

        public FracturePiece(int body) { Body = body; }
    }

    /// <summary>What one hit on a piece did (docs/FORMAT.md section 14.5).</summary>
    public sealed class FracturePieceHit
    {
        public readonly int Struck, Body, ChildBody;
        /// <summary>Body's answer after the hit (local indices; Groups over all its children).</summary>
        public readonly FractureImpact Result;
        /// <summary>The struck fragment's own body's answer, null when it has no children.</summary>
        public readonly FractureImpact ChildResult;
        /// <summary>Whether the struck fragment broke into its children.</summary>
        public readonly bool Split;
        /// <summary>The pieces the hit piece became: its fragments regrouped, then its children's pieces.</summary>
        public readonly List<FracturePiece> Pieces;

        public FracturePieceHit(int struck, int body, FractureImpact result, int childBody, FractureImpact childResult,
                                bool split, List<FracturePiece> pieces)
        {
            Struck = struck;
            Body = body;
            Result = result;
            ChildBody = childBody;
            ChildResult = childResult;
            Split = split;
            Pieces = pieces;
        }
    }

    /// <summary>A loaded, validated runtime file (immutable: Project may run on several threads).</summary>
    public sealed class FractureRuntime
    {
        /// <summary>Highest file format version this reader reads (2: the features of docs/FORMAT.md sections 11-12).</summary>
        public const int FormatVersion = 2;
        /// <summary>The version-2 features this reader implements.</summary>
        public static readonly string[] KnownFeatures = { "anchors", "damage", "levels", "stress" };
        const double BoundSlack = 1e-9;
        const int KdLeaf = 16;
        /// <summary>Largest d = 1 jump table Load builds, in bytes (see <see cref="Load"/>).</summary>
        public const long TableMaxBytes = 16L << 20;

        public readonly int Sites, Modes, Fragments, Edges, Dim;
        public readonly double DefaultThreshold, ImpactRadius;
        readonly double[] transform = new double[16];
        readonly string[] names;
        readonly float[] sites, B, edgeAreas;
        readonly double[] W;
        readonly int[] edges;
        // k-d tree (sites in tree order), groups when nothing breaks, the largest per-edge bound.
        readonly double[] kdPoints, kdBoxes;
        readonly int[] kdIndex, kdNodes;
        readonly int[] whole, identity;
        readonly int wholeGroups;
        double maxBound;
        // d = 1 jump table (null when not built), see BuildJumpTable: per site, |J[v, m]| ascending with its
        // edge, and the merges of Kruskal's algorithm over that row (p entries per site).
        readonly double[] jumps;
        readonly ushort[] jumpEdge, mergeAt, mergeChild;
        readonly int[] mergeLabel;
        readonly int merges;
        readonly bool[] allBroken; // [e] all true
        // Criterion "stress" (docs/FORMAT.md section 11; null otherwise): site v's bonds are entries
        // bondPtr[v] .. bondPtr[v + 1] - 1 of bondEdge and bondGain (G, 3 per entry); bondStrength (S) per edge.
        readonly int[] bondPtr, bondEdge;
        readonly float[] bondGain, bondStrength;

        /// <summary>How a hit decides which bonds break: "modes" (section 4) or "stress" (section 11).</summary>
        public readonly string Criterion;
        /// <summary>Stress criterion: entries of the per-site bond lists (counts.site_bonds); 0 otherwise.</summary>
        public readonly int SiteBonds;

        // Section 12: anchored flags (null without "anchors"), the damage parameters, the crack arrays (null without).
        readonly int[] anchored, crackPtr;
        readonly float[] crackSegments;
        readonly double damageQ;
        /// <summary>Feature "anchors": some fragments are bonded to the world (<see cref="IsAnchored"/>).</summary>
        public readonly bool HasAnchors;
        /// <summary>Feature "damage": hits below a bond's strength crack it and lower its health (<see cref="Hit"/>).</summary>
        public readonly bool HasDamage;
        /// <summary>Feature "damage": the crack level c in (0, 1]; 1 without it (a state then only remembers broken bonds).</summary>
        public readonly double CrackLevel = 1.0;
        /// <summary>Feature "damage": the damage rate r &gt;= 0; 0 without it.</summary>
        public readonly double DamageRate;
        /// <summary>Segments of the optional crack arrays (<see cref="CrackSegments"/>); 0 without them.</summary>
        public readonly int CrackSegmentCount;

        /// <summary>Whether the fragment is bonded to the world (false for every fragment without feature "anchors").</summary>
        public bool IsAnchored(int fragment) { return anchored != null && anchored[fragment] == 1; }

        /// <summary>
        /// Where a bond's fault meets the outer surface, for drawing a cracked bond: segments
        /// <paramref name="first"/> .. first + count - 1 of <see cref="CrackSegmentCoordinate"/>; returns the
        /// count (0 without the crack arrays).
        /// </summary>
        public int CrackSegments(int bond, out int first)
        {
            if (bond < 0 || bond >= Edges)
                throw new ArgumentOutOfRangeException("bond");
            first = crackPtr != null ? crackPtr[bond] : 0;
            return crackPtr != null ? crackPtr[bond + 1] - crackPtr[bond] : 0;
        }

        /// <summary>Coordinate <paramref name="axis"/> (0-2) of end <paramref name="end"/> (0-1) of a crack segment, model space.</summary>
        public float CrackSegmentCoordinate(int segment, int end, int axis) { return crackSegments[6 * segment + 3 * end + axis]; }

        /// <summary>Whether Load built the d = 1 jump table (the fast path; see <see cref="Load"/>).</summary>
        public bool HasJumpTable { get { return jumps != null; } }

        /// <summary>Row-major 4x4 matrix, normalized bake coordinates to model space (informational).</summary>
        public double[] Transform { get { return (double[])transform.Clone(); } }
        public string FragmentName(int fragment) { return names[fragment]; }
        public IList<string> FragmentNames { get { return Array.AsReadOnly(names); } }
        /// <summary>(e, 2) fragment pairs (P, Q), P &lt; Q.</summary>
        public int EdgeFragment(int edge, int end) { return edges[2 * edge + end]; }
        public float EdgeArea(int edge) { return edgeAreas[edge]; }
        public float SiteCoordinate(int site, int axis) { return sites[3 * site + axis]; }

        /// <summary>
        /// Parse and validate; throws <see cref="FractureRuntimeException"/> for a bad file. For a d = 1
        /// file it also tabulates per contact site the edges' jumps in ascending order and the order in
        /// which they join fragments, so a projection is a bisection and one pass over at most p merges:
        /// (10 e + 10 p) bytes per site (6 MB for a vase with s = 1002, p = 189, e = 435), skipped above
        /// <see cref="TableMaxBytes"/>, for d = 3 and with <paramref name="compact"/> (then a projection
        /// computes the displacements and tests every edge: slower on files with hundreds of edges, same
        /// answers).
        /// </summary>
        public static FractureRuntime Load(byte[] header, byte[] binary, bool checkCrc = true, bool compact = false)
        {
            if (header == null || binary == null)
                throw new FractureRuntimeException(FractureStatus.Argument, "null header or binary");
            return new FractureRuntime(Header.Parse(header), binary, checkCrc, compact);
        }

        /// <summary>Like <see cref="Load"/>, returning false and a one-line reason instead of throwing.</summary>
        public static bool TryLoad(byte[] header, byte[] binary, out FractureRuntime runtime, out string error,
                                   bool checkCrc = true, bool compact = false)
        {
            try
            {
                runtime = Load(header, binary, checkCrc, compact);
                error = null;
                return true;
            }
            catch (FractureRuntimeException exception)
            {
                runtime = null;
                error = exception.Message;
                return false;
            }
        }

        /// <summary>The binary file name (buffer.uri) a header points to: a plain name in its folder.</summary>
        public static string HeaderUri(byte[] header)
        {
            Header h = Header.Parse(header);
            h.CheckUri();
            return h.Uri;
        }

        FractureRuntime(Header h, byte[] binary, bool checkCrc, bool compact)
        {
            h.CheckKeys();
            h.CheckUri();
            if (h.ByteLength != binary.LongLength)
                throw Fail(FractureStatus.Size, "binary file has " + binary.LongLength + " bytes but the header says " +
                                                h.ByteLength + " (truncated or from another bake)");
            if (h.HasCrc && (h.Crc < 0 || h.Crc > 0xFFFFFFFFL))
                throw Fail(FractureStatus.Header, "buffer.crc32 must be a 32-bit unsigned integer");
            if (h.HasCrc && checkCrc && Crc32(binary) != (uint)h.Crc)
                throw Fail(FractureStatus.Crc, "binary file does not match its header (crc32 differs; from another bake?)");
            h.CheckArrays(binary.LongLength);
            long[] s = h.Arrays[0].Shape, b = h.Arrays[1].Shape, w = h.Arrays[2].Shape;
            long[] e = h.Arrays[3].Shape, a = h.Arrays[4].Shape;
            long d = w[2];
            if (d != 1 && d != 3)
                throw Fail(FractureStatus.Size, "W must have d = 1 or 3, got " + d);
            if (s[1] != 3 || b[0] != s[0] || b[1] != w[0] || b[2] != d || e[1] != 2 || a[0] != e[0])
                throw Fail(FractureStatus.Size, "array shapes do not agree with each other");
            if (s[0] < 1 || w[0] < 1 || w[1] < 1)
                throw Fail(FractureStatus.Size, "need at least one site, mode and fragment");
            if (s[0] > int.MaxValue || w[0] > int.MaxValue || w[1] > int.MaxValue || e[0] > int.MaxValue)
                throw Fail(FractureStatus.Size, "counts beyond 2^31");
            if (h.Dim != d)
                throw Fail(FractureStatus.Size, "header says dim = " + h.Dim + " but W has d = " + d);
            if (h.Counts == null || h.Counts[0] != s[0] || h.Counts[1] != w[0] || h.Counts[2] != w[1] || h.Counts[3] != e[0])
                throw Fail(FractureStatus.Size, "header counts do not match the arrays");
            if (h.Names == null || h.Names.Length != w[1])
                throw Fail(FractureStatus.Header, "fragment_names must be " + w[1] + " strings");
            if (!IsFinite(h.DefaultThreshold) || h.DefaultThreshold < 0)
                throw Fail(FractureStatus.Header, "default_threshold must be a finite number >= 0");
            if (!IsFinite(h.ImpactRadius))
                throw Fail(FractureStatus.Header, "impact_radius must be finite");
            for (int i = 0; i < 16; i++)
                if (!IsFinite(h.Transform[i]))
                    throw Fail(FractureStatus.Header, "transform must be 16 finite numbers");
            Sites = (int)s[0];
            Modes = (int)w[0];
            Fragments = (int)w[1];
            Dim = (int)d;
            Edges = (int)e[0];
            DefaultThreshold = h.DefaultThreshold;
            ImpactRadius = h.ImpactRadius;
            Array.Copy(h.Transform, transform, 16);
            names = h.Names;
            sites = ReadFloats(binary, h.Arrays[0], "sites");
            B = ReadFloats(binary, h.Arrays[1], "B");
            float[] w32 = ReadFloats(binary, h.Arrays[2], "W");
            W = new double[w32.Length];
            for (int i = 0; i < w32.Length; i++)
                W[i] = w32[i];
            edgeAreas = ReadFloats(binary, h.Arrays[4], "edge_areas");
            edges = new int[2 * Edges];
            for (int m = 0; m < 2 * Edges; m++)
                edges[m] = ReadInt(binary, h.Arrays[3].Offset + 4 * m);
            for (int m = 0; m < Edges; m++)
                if (edges[2 * m] < 0 || edges[2 * m] >= edges[2 * m + 1] || edges[2 * m + 1] >= Fragments)
                    throw Fail(FractureStatus.Data, "edge " + m + " is (" + edges[2 * m] + ", " + edges[2 * m + 1] +
                                                    "): edges must be (P, Q) with 0 <= P < Q < " + Fragments);
            Criterion = h.Stress ? "stress" : "modes";
            if (h.Stress)
            {
                long[] ptrShape = h.Arrays[5].Shape, bondsShape = h.Arrays[6].Shape;
                long[] gainShape = h.Arrays[7].Shape, strengthShape = h.Arrays[8].Shape;
                long nnz = bondsShape[0];
                if (nnz > int.MaxValue)
                    throw Fail(FractureStatus.Size, "counts beyond 2^31");
                if (ptrShape[0] != Sites + 1L || gainShape[0] != nnz || gainShape[1] != 3 || strengthShape[0] != Edges)
                    throw Fail(FractureStatus.Size, "stress arrays must be site_bonds_ptr (s + 1), site_bonds (nnz), " +
                                                    "site_bond_gain (nnz, 3) and bond_strength (e)");
                if (h.SiteBondsCount != nnz)
                    throw Fail(FractureStatus.Size, "header counts.site_bonds does not match the arrays");
                SiteBonds = (int)nnz;
                bondPtr = ReadInts(binary, h.Arrays[5]);
                bondEdge = ReadInts(binary, h.Arrays[6]);
                CheckBondLists();
                bondGain = ReadFloats(binary, h.Arrays[7], "site_bond_gain");
                bondStrength = ReadFloats(binary, h.Arrays[8], "bond_strength");
                for (int m = 0; m < Edges; m++)
                    if (bondStrength[m] < 0)
                        throw Fail(FractureStatus.Data, "bond_strength must be >= 0");
            }
            HasAnchors = h.Anchors;
            if (HasAnchors)
            {
                if (h.Arrays[9].Shape[0] != Fragments)
                    throw Fail(FractureStatus.Size, "array anchored has shape [" + h.Arrays[9].Shape[0] +
                                                    "], expected [" + Fragments + "]");
                anchored = ReadInts(binary, h.Arrays[9]);
                foreach (int flag in anchored)
                    if (flag != 0 && flag != 1)
                        throw Fail(FractureStatus.Data, "array anchored must hold only 0 and 1");
            }
            if (h.Cracks)
            {
                long[] ptrShape = h.Arrays[10].Shape, segmentShape = h.Arrays[11].Shape;
                if (segmentShape[0] > int.MaxValue)
                    throw Fail(FractureStatus.Size, "counts beyond 2^31");
                if (ptrShape[0] != Edges + 1L || segmentShape[1] != 2 || segmentShape[2] != 3)
                    throw Fail(FractureStatus.Size, "crack arrays must be crack_ptr (e + 1) and crack_segments (n, 2, 3)");
                if (h.CrackSegmentsCount != segmentShape[0])
                    throw Fail(FractureStatus.Size, "header counts.crack_segments does not match the arrays");
                CrackSegmentCount = (int)segmentShape[0];
                crackPtr = ReadInts(binary, h.Arrays[10]);
                bool bad = crackPtr[0] != 0 || crackPtr[Edges] != CrackSegmentCount;
                for (int m = 0; m < Edges && !bad; m++)
                    bad = crackPtr[m + 1] < crackPtr[m];
                if (bad)
                    throw Fail(FractureStatus.Data, "crack_ptr must start at 0, never decrease and end at " + CrackSegmentCount);
                crackSegments = ReadFloats(binary, h.Arrays[11], "crack_segments");
            }
            HasDamage = h.Damage;
            if (HasDamage)
            {
                h.CheckDamage();
                CrackLevel = h.CrackLevel;
                DamageRate = h.DamageRate;
            }
            damageQ = CrackLevel == 1.0 ? 0.0 : DamageRate / (1.0 - CrackLevel); // q = r / (1 - c), once per file
            kdIndex = new int[Sites];
            kdPoints = new double[3 * Sites];
            int kdCapacity = 4 * (Sites / KdLeaf) + 2; // a leaf holds at least KdLeaf / 2 sites
            kdNodes = new int[4 * kdCapacity];
            kdBoxes = new double[6 * kdCapacity];
            BuildKdTree();
            identity = new int[Fragments];
            whole = new int[Fragments];
            for (int j = 0; j < Fragments; j++)
                identity[j] = whole[j] = j;
            for (int m = 0; m < Edges; m++)
                Unite(whole, edges[2 * m], edges[2 * m + 1]);
            wholeGroups = Label(whole, Fragments, whole);
            EdgeBounds();
            if (!compact && !h.Stress && Dim == 1 && Edges > 0 && Edges <= ushort.MaxValue && Fragments <= short.MaxValue &&
                (10L * Edges + 10L * Fragments) * Sites <= TableMaxBytes)
            {
                jumps = new double[(long)Sites * Edges];
                jumpEdge = new ushort[(long)Sites * Edges];
                mergeAt = new ushort[(long)Sites * Fragments];
                mergeChild = new ushort[2L * Sites * Fragments];
                mergeLabel = new int[(long)Sites * Fragments];
                merges = BuildJumpTable();
                allBroken = new bool[Edges];
                for (int m = 0; m < Edges; m++)
                    allBroken[m] = true;
            }
            if (h.Levels)
                ReadLevels(h, binary, compact);
        }

        // site_bonds_ptr starts at 0, never decreases and ends at nnz; site_bonds are edge indices, strictly
        // ascending within a site (docs/FORMAT.md section 11).
        void CheckBondLists()
        {
            int nnz = bondEdge.Length;
            if (bondPtr[0] != 0 || bondPtr[Sites] != nnz)
                throw Fail(FractureStatus.Data, "site_bonds_ptr must start at 0, never decrease and end at " + nnz);
            for (int v = 0; v < Sites; v++)
                if (bondPtr[v + 1] < bondPtr[v])
                    throw Fail(FractureStatus.Data, "site_bonds_ptr must start at 0, never decrease and end at " + nnz);
            for (int v = 0; v < Sites; v++)
                for (int j = bondPtr[v]; j < bondPtr[v + 1]; j++)
                {
                    if (bondEdge[j] < 0 || bondEdge[j] >= Edges)
                        throw Fail(FractureStatus.Data, "site_bonds must be bond indices in 0.." + (Edges - 1));
                    if (j > bondPtr[v] && bondEdge[j] <= bondEdge[j - 1])
                        throw Fail(FractureStatus.Data, "site_bonds must be strictly ascending within each site");
                }
        }

        static int[] ReadInts(byte[] data, ArrayEntry entry)
        {
            var values = new int[entry.Length / 4];
            for (int i = 0; i < values.Length; i++)
                values[i] = ReadInt(data, entry.Offset + 4L * i);
            return values;
        }

        static FractureRuntimeException Fail(FractureStatus status, string message)
        {
            return new FractureRuntimeException(status, message);
        }

        static bool IsFinite(double x) { return !double.IsNaN(x) && !double.IsInfinity(x); }

        [StructLayout(LayoutKind.Explicit)]
        struct Bits32
        {
            [FieldOffset(0)] public int Int;
            [FieldOffset(0)] public float Float;
        }

        static int ReadInt(byte[] data, long at)
        {
            return data[at] | data[at + 1] << 8 | data[at + 2] << 16 | data[at + 3] << 24;
        }

        static float[] ReadFloats(byte[] data, ArrayEntry entry, string name)
        {
            var values = new float[entry.Length / 4];
            var bits = new Bits32();
            for (int i = 0; i < values.Length; i++)
            {
                bits.Int = ReadInt(data, entry.Offset + 4L * i);
                if ((bits.Int & 0x7F800000) == 0x7F800000)
                    throw Fail(FractureStatus.Data, "array '" + name + "' has non-finite values");
                values[i] = bits.Float;
            }
            return values;
        }

        static uint Crc32(byte[] data)
        {
            var table = new uint[256];
            for (uint i = 0; i < 256; i++)
            {
                uint c = i;
                for (int k = 0; k < 8; k++)
                    c = (c & 1) != 0 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
                table[i] = c;
            }
            uint crc = 0xFFFFFFFFu;
            foreach (byte x in data)
                crc = table[(crc ^ x) & 0xFF] ^ (crc >> 8);
            return crc ^ 0xFFFFFFFFu;
        }

        // ------------------------------------------------------------------ nearest site (k-d tree)

        void BuildKdTree()
        {
            for (int i = 0; i < Sites; i++)
                kdIndex[i] = i;
            int count = 0;
            KdBuild(0, Sites, ref count);
            for (int i = 0; i < Sites; i++)
                for (int c = 0; c < 3; c++)
                    kdPoints[3 * i + c] = sites[3 * kdIndex[i] + c];
        }

        // Node n: kdNodes[4n..] = begin, end, left, right (left < 0: a leaf); kdBoxes[6n..] = lo, hi.
        int KdBuild(int begin, int end, ref int count)
        {
            int id = count++, axis = 0;
            for (int c = 0; c < 3; c++)
            {
                double lo = sites[3 * kdIndex[begin] + c], hi = lo;
                for (int i = begin + 1; i < end; i++)
                {
                    double v = sites[3 * kdIndex[i] + c];
                    lo = Math.Min(lo, v);
                    hi = Math.Max(hi, v);
                }
                kdBoxes[6 * id + c] = lo;
                kdBoxes[6 * id + 3 + c] = hi;
                if (hi - lo > kdBoxes[6 * id + 3 + axis] - kdBoxes[6 * id + axis])
                    axis = c;
            }
            kdNodes[4 * id] = begin;
            kdNodes[4 * id + 1] = end;
            kdNodes[4 * id + 2] = kdNodes[4 * id + 3] = -1;
            if (end - begin <= KdLeaf)
                return id;
            int mid = begin + (end - begin) / 2;
            Select(begin, end - 1, mid, axis);
            kdNodes[4 * id + 2] = KdBuild(begin, mid, ref count);
            kdNodes[4 * id + 3] = KdBuild(mid, end, ref count);
            return id;
        }

        // Quickselect on kdIndex[lo..hi] by coordinate `axis`; any split is correct (boxes are exact).
        void Select(int lo, int hi, int nth, int axis)
        {
            while (hi > lo)
            {
                float pivot = sites[3 * kdIndex[lo + (hi - lo) / 2] + axis];
                int i = lo, j = hi;
                while (i <= j)
                {
                    while (sites[3 * kdIndex[i] + axis] < pivot) i++;
                    while (sites[3 * kdIndex[j] + axis] > pivot) j--;
                    if (i <= j)
                    {
                        int t = kdIndex[i];
                        kdIndex[i++] = kdIndex[j];
                        kdIndex[j--] = t;
                    }
                }
                if (nth <= j) hi = j;
                else if (nth >= i) lo = i;
                else break;
            }
        }

        // Squared distance to a node's box, computed like a site's so it never exceeds one inside.
        double BoxDistance2(int node, double x, double y, double z)
        {
            int b = 6 * node;
            double dx = x < kdBoxes[b] ? kdBoxes[b] - x : x > kdBoxes[b + 3] ? x - kdBoxes[b + 3] : 0.0;
            double dy = y < kdBoxes[b + 1] ? kdBoxes[b + 1] - y : y > kdBoxes[b + 4] ? y - kdBoxes[b + 4] : 0.0;
            double dz = z < kdBoxes[b + 2] ? kdBoxes[b + 2] - z : z > kdBoxes[b + 5] ? z - kdBoxes[b + 5] : 0.0;
            return dx * dx + dy * dy + dz * dz;
        }

        internal const int KdStack = 96; // deeper than any tree of at most 2^31 sites

        [ThreadStatic] static int[] threadIds;
        [ThreadStatic] static double[] threadBounds;

        /// <summary>Nearest contact site (smallest index on exact ties, docs/FORMAT.md section 4 step 1).</summary>
        public int NearestSite(double x, double y, double z)
        {
            if (!IsFinite(x) || !IsFinite(y) || !IsFinite(z))
                return -1;
            if (threadIds == null)
            {
                threadIds = new int[KdStack];
                threadBounds = new double[KdStack];
            }
            return NearestSiteCore(x, y, z, threadIds, threadBounds);
        }

        // A box is skipped only when strictly farther than the best site, so ties keep the smallest index.
        int NearestSiteCore(double x, double y, double z, int[] ids, double[] bounds)
        {
            int top = 1, bestIndex = int.MaxValue;
            double best = double.PositiveInfinity;
            ids[0] = 0;
            bounds[0] = BoxDistance2(0, x, y, z);
            while (top > 0)
            {
                top--;
                if (bounds[top] > best)
                    continue;
                int node = ids[top], left = kdNodes[4 * node + 2], right = kdNodes[4 * node + 3];
                if (left < 0)
                {
                    for (int i = kdNodes[4 * node]; i < kdNodes[4 * node + 1]; i++)
                    {
                        double dx = kdPoints[3 * i] - x, dy = kdPoints[3 * i + 1] - y, dz = kdPoints[3 * i + 2] - z;
                        double d2 = dx * dx + dy * dy + dz * dz;
                        if (d2 < best || (d2 == best && kdIndex[i] < bestIndex))
                        {
                            best = d2;
                            bestIndex = kdIndex[i];
                        }
                    }
                    continue;
                }
                double a = BoxDistance2(left, x, y, z), b = BoxDistance2(right, x, y, z);
                bool leftNear = a <= b;
                ids[top] = leftNear ? right : left; // pushed first: the nearer box is searched first
                bounds[top++] = leftNear ? b : a;
                ids[top] = leftNear ? left : right;
                bounds[top++] = leftNear ? a : b;
            }
            return bestIndex;
        }

        // ------------------------------------------------------------------ fragment graph

        static int Root(int[] parent, int a)
        {
            while (parent[a] != a)
                a = parent[a] = parent[parent[a]]; // path halving
            return a;
        }

        // One unbroken edge: hook the larger root under the smaller, so every parent is smaller than its child.
        static void Unite(int[] parent, int P, int Q)
        {
            int a = Root(parent, P), b = Root(parent, Q);
            parent[Math.Max(a, b)] = Math.Min(a, b);
        }

        // After every Unite: since parents are smaller, one forward pass turns each entry into its root, the
        // component's smallest fragment (the group id). Returns the number of groups.
        static int Label(int[] parent, int p, int[] groups)
        {
            int count = 0;
            for (int j = 0; j < p; j++)
            {
                int root = parent[parent[j]];
                parent[j] = groups[j] = root;
                count += root == j ? 1 : 0;
            }
            return count;
        }

        // The largest over edges of c with |jump'| <= |alpha'| * c for the computed jump: Cauchy-Schwarz on
        // W[:, P] - W[:, Q] plus slack for the rounding of both displacements.
        void EdgeBounds()
        {
            int n = Fragments * Dim;
            for (int m = 0; m < Edges; m++)
            {
                int P = edges[2 * m], Q = edges[2 * m + 1];
                double diff2 = 0, wp2 = 0, wq2 = 0;
                for (int i = 0; i < Modes; i++)
                    for (int c = 0; c < Dim; c++)
                    {
                        double wp = W[i * n + P * Dim + c], wq = W[i * n + Q * Dim + c];
                        diff2 += (wp - wq) * (wp - wq);
                        wp2 += wp * wp;
                        wq2 += wq * wq;
                    }
                double bound = (Math.Sqrt(diff2) + BoundSlack * (Math.Sqrt(wp2) + Math.Sqrt(wq2))) * (1.0 + BoundSlack);
                maxBound = Math.Max(maxBound, bound);
            }
        }

        // The d = 1 jump table (docs/FORMAT.md section 4, "Cost"): J[v, m] = sum over i of
        // B[v, i] (W[i, P] - W[i, Q]), so |jump'| = |n'| |J[v, m]|, and x -> |n'| x rounds monotonically: the
        // edges that hold are a prefix of the row sorted by |J|. Kruskal's algorithm over the row gives the
        // merges whose clusters are the groups. Returns the number of merges (the same for every site).
        int BuildJumpTable()
        {
            int k = Modes, e = Edges, p = Fragments, count = 0;
            var diff = new double[e * k];
            for (int m = 0; m < e; m++)
                for (int i = 0; i < k; i++)
                    diff[m * k + i] = W[i * p + edges[2 * m]] - W[i * p + edges[2 * m + 1]];
            var keys = new double[e];
            var items = new int[e];
            var uf = new int[p];
            var cluster = new int[p];
            for (int v = 0; v < Sites; v++)
            {
                for (int m = 0; m < e; m++)
                {
                    double sum = 0;
                    for (int i = 0; i < k; i++)
                        sum += (double)B[v * k + i] * diff[m * k + i];
                    keys[m] = Math.Abs(sum);
                    items[m] = m;
                }
                Array.Sort(keys, items); // ties in any order: they hold or break together
                long row = (long)v * e, at = (long)v * p;
                for (int m = 0; m < e; m++)
                {
                    jumps[row + m] = keys[m];
                    jumpEdge[row + m] = (ushort)items[m];
                }
                for (int j = 0; j < p; j++)
                    uf[j] = cluster[j] = j;
                count = 0;
                for (int pos = 0; pos < e; pos++)
                {
                    int a = Root(uf, edges[2 * items[pos]]), b = Root(uf, edges[2 * items[pos] + 1]);
                    if (a == b)
                        continue;
                    int lo = Math.Min(a, b), hi = Math.Max(a, b);
                    mergeAt[at + count] = (ushort)pos;
                    mergeChild[2 * (at + count)] = (ushort)cluster[a];
                    mergeChild[2 * (at + count) + 1] = (ushort)cluster[b];
                    mergeLabel[at + count] = lo; // roots are their component's smallest fragment
                    uf[hi] = lo;
                    cluster[lo] = p + count++;
                }
            }
            return count;
        }

        // ------------------------------------------------------------------ projection

        /// <summary>
        /// Project a hit (docs/FORMAT.md section 4): point in model space, impulse in model axes (any
        /// unit), threshold in the impulse's unit (double.PositiveInfinity: unbreakable). Fills
        /// <paramref name="result"/> without allocating; returns Input for a non-finite point or
        /// impulse or a NaN or negative threshold (result untouched). On a file with feature "damage"
        /// this is <see cref="Hit"/> on a fresh state that is then thrown away (so it also answers
        /// Cracked); Anchored is answered for every file.
        /// </summary>
        public FractureStatus Project(double px, double py, double pz, double nx, double ny, double nz, double threshold,
                                      FractureImpact result)
        {
            if (result == null || result.Owner != this)
                return FractureStatus.Argument;
            if (!IsFinite(px) || !IsFinite(py) || !IsFinite(pz) || !IsFinite(nx) || !IsFinite(ny) || !IsFinite(nz))
                return FractureStatus.Input;
            if (double.IsNaN(threshold) || threshold < 0)
                return FractureStatus.Input;
            if (HasDamage) // section 12.4: a hit on a fresh state
            {
                ResetState(result.FreshHealth);
                HitCore(result.FreshHealth, px, py, pz, nx, ny, nz, threshold, result);
                return FractureStatus.Ok;
            }
            Array.Clear(result.Cracked, 0, Edges); // nothing cracks without feature "damage"
            result.NumCracked = 0;
            ProjectCore(px, py, pz, nx, ny, nz, threshold, result);
            AnchoredGroups(result);
            return FractureStatus.Ok;
        }

        void ProjectCore(double px, double py, double pz, double nx, double ny, double nz, double threshold,
                         FractureImpact result)
        {
            double m = Math.Max(Math.Abs(nx), Math.Max(Math.Abs(ny), Math.Abs(nz))), t = 0, length = 0;
            double[] alpha = result.ScaledAlpha, disp = result.ScaledDisp;
            result.Site = NearestSiteCore(px, py, pz, result.KdIds, result.KdBounds);
            bool breaks = false;
            if (m == 0)
            {
                Array.Clear(alpha, 0, alpha.Length);
            }
            else
            {
                double n0 = nx / m, n1 = ny / m, n2 = nz / m;
                t = threshold / m;
                length = Math.Sqrt(n0 * n0 + n1 * n1 + n2 * n2);
                ModeCoefficients(result.Site, n0, n1, n2, length, alpha);
                if (bondPtr != null)
                {
                    if (result.ComputeDisplacement)
                        Displacements(alpha, disp);
                    result.NumGroups = StressGroups(result.Site, n0, n1, n2, t, result);
                    if (result.ComputeDisplacement)
                        for (int i = 0; i < disp.Length; i++)
                            result.Displacement[i] = m * disp[i];
                    for (int i = 0; i < Modes; i++)
                        result.Alpha[i] = m * alpha[i];
                    return;
                }
                if (jumps != null)
                {
                    breaks = !(length * jumps[(long)result.Site * Edges + Edges - 1] <= t); // the row's largest
                }
                else
                {
                    double norm2 = 0;
                    for (int i = 0; i < Modes; i++)
                        norm2 += alpha[i] * alpha[i];
                    breaks = !(Math.Sqrt(norm2) * (1.0 + BoundSlack) * maxBound <= t);
                }
            }
            if (result.ComputeDisplacement || (breaks && jumps == null))
                Displacements(alpha, disp);
            if (breaks && jumps != null)
            {
                result.NumGroups = TableGroups(result.Site, length, t, result);
            }
            else if (breaks)
            {
                result.NumGroups = DirectGroups(t, result);
            }
            else
            {
                Array.Clear(result.Broken, 0, Edges);
                Array.Copy(whole, result.Groups, Fragments);
                result.NumGroups = wholeGroups;
                result.NumBroken = 0;
            }
            if (result.ComputeDisplacement)
                for (int i = 0; i < disp.Length; i++)
                    result.Displacement[i] = m * disp[i];
            for (int i = 0; i < Modes; i++)
                result.Alpha[i] = m * alpha[i];
        }

        void ModeCoefficients(int site, double n0, double n1, double n2, double length, double[] alpha)
        {
            int b = site * Modes * Dim;
            if (Dim == 1)
            {
                for (int i = 0; i < Modes; i++)
                    alpha[i] = (double)B[b + i] * length;
            }
            else
            {
                for (int i = 0; i < Modes; i++)
                    alpha[i] = (double)B[b + 3 * i] * n0 + (double)B[b + 3 * i + 1] * n1 + (double)B[b + 3 * i + 2] * n2;
            }
        }

        // disp'[j, c] = sum over i of alpha'[i] W[i, j, c], each sum in mode order.
        void Displacements(double[] alpha, double[] disp)
        {
            int n = Fragments * Dim;
            Array.Clear(disp, 0, n);
            for (int i = 0; i < Modes; i++)
            {
                double a = alpha[i];
                int row = i * n;
                for (int j = 0; j < n; j++)
                    disp[j] += a * W[row + j];
            }
        }

        // Step 5 from the jump table (d = 1): the number of edges that hold, |n'| |J[v, m]| <= t (a prefix of the row).
        int TableHolding(int site, double length, double t)
        {
            long row = (long)site * Edges;
            int lo = 0, hi = Edges;
            while (lo < hi)
            {
                int mid = lo + (hi - lo) / 2;
                if (length * jumps[row + mid] <= t) lo = mid + 1;
                else hi = mid;
            }
            return lo;
        }

        // The number of the site's merges whose edge lies in the first `holding` positions of its row (a prefix).
        int MergesDone(int site, int holding)
        {
            long at = (long)site * Fragments;
            int lo = 0, hi = merges;
            while (lo < hi)
            {
                int mid = lo + (hi - lo) / 2;
                if (mergeAt[at + mid] < holding) lo = mid + 1;
                else hi = mid;
            }
            return lo;
        }

        // The groups of the site's first `done` merges: labels[0, p) start as each fragment's own index and
        // labels[p + r] as merge r's smallest fragment; top-down over the done merges (a merge's parent comes
        // later), each passes its label on to its two children. Returns the number of groups.
        int MergeGroups(int site, int done, int[] labels, int[] groups)
        {
            int p = Fragments;
            long at = (long)site * p;
            Array.Copy(identity, labels, p);
            Array.Copy(mergeLabel, at, labels, p, done);
            for (int r = done - 1; r >= 0; r--)
            {
                int value = labels[p + r];
                labels[mergeChild[2 * (at + r)]] = value;
                labels[mergeChild[2 * (at + r) + 1]] = value;
            }
            Array.Copy(labels, groups, p);
            return p - done;
        }

        // Steps 5-6 with the jump table: the edges that hold are the row's first `holding`, the groups those of
        // the merges inside that prefix.
        int TableGroups(int site, double length, double t, FractureImpact result)
        {
            int e = Edges, holding = TableHolding(site, length, t);
            long row = (long)site * e;
            bool[] broken = result.Broken;
            Array.Copy(allBroken, broken, e); // a block copy: much faster than a loop in Mono
            for (int i = 0; i < holding; i++)
                broken[jumpEdge[row + i]] = false;
            result.NumBroken = e - holding;
            return MergeGroups(site, MergesDone(site, holding), result.Labels, result.Groups);
        }

        // Criterion "stress" (docs/FORMAT.md section 11): bond e of the site's list breaks when
        // g = (G0 n'0 + G1 n'1) + G2 n'2 exceeds t * S[e] (strictly; in this order); every other bond holds.
        // Then step 6 over the bonds that hold.
        int StressGroups(int site, double n0, double n1, double n2, double t, FractureImpact result)
        {
            bool[] broken = result.Broken;
            int count = 0;
            Array.Clear(broken, 0, Edges);
            for (int j = bondPtr[site]; j < bondPtr[site + 1]; j++)
            {
                int b = 3 * j, e = bondEdge[j];
                double g = (double)bondGain[b] * n0 + (double)bondGain[b + 1] * n1 + (double)bondGain[b + 2] * n2;
                if (g > t * (double)bondStrength[e])
                {
                    broken[e] = true;
                    count++;
                }
            }
            result.NumBroken = count;
            if (count == 0)
            {
                Array.Copy(whole, result.Groups, Fragments);
                return wholeGroups;
            }
            int[] uf = result.Labels;
            Array.Copy(identity, uf, Fragments);
            for (int m = 0; m < Edges; m++)
                if (!broken[m])
                    Unite(uf, edges[2 * m], edges[2 * m + 1]);
            return Label(uf, Fragments, result.Groups);
        }

        // Steps 5-6 from the displacements: test every edge, union-find over those that hold.
        int DirectGroups(double t, FractureImpact result)
        {
            double[] disp = result.ScaledDisp;
            bool[] broken = result.Broken;
            int[] uf = result.Labels;
            int count = 0;
            Array.Copy(identity, uf, Fragments);
            for (int m = 0; m < Edges; m++)
            {
                broken[m] = EdgeJump(disp, m) > t;
                if (broken[m])
                    count++;
                else
                    Unite(uf, edges[2 * m], edges[2 * m + 1]);
            }
            result.NumBroken = count;
            return Label(uf, Fragments, result.Groups);
        }

        // Step 5: |jump'| of edge m from the displacements, |disp'[P] - disp'[Q]| (Euclidean norm when d = 3).
        double EdgeJump(double[] disp, int m)
        {
            int P = edges[2 * m], Q = edges[2 * m + 1];
            if (Dim == 1)
                return Math.Abs(disp[P] - disp[Q]);
            double j0 = disp[3 * P] - disp[3 * Q], j1 = disp[3 * P + 1] - disp[3 * Q + 1];
            double j2 = disp[3 * P + 2] - disp[3 * Q + 2];
            return Math.Sqrt(j0 * j0 + j1 * j1 + j2 * j2);
        }

        // Section 12.4 step 4, Anchored: true for the fragments whose group holds a fragment bonded to the world.
        // A group id is its smallest fragment, so the first pass marks group ids and the second, in fragment
        // order, copies each group's mark to its members (Groups[j] <= j, and a group id keeps its own mark).
        void AnchoredGroups(FractureImpact result)
        {
            bool[] held = result.Anchored;
            int[] groups = result.Groups;
            Array.Clear(held, 0, Fragments);
            if (anchored == null)
                return;
            for (int j = 0; j < Fragments; j++)
                if (anchored[j] == 1)
                    held[groups[j]] = true;
            for (int j = 0; j < Fragments; j++)
                held[j] = held[groups[j]];
        }

        // ------------------------------------------------------------------ damage (docs/FORMAT.md section 12)

        /// <summary>A fresh damage state for one object: e bond healths, all 1 (no bond damaged).</summary>
        public double[] NewState()
        {
            var health = new double[Edges];
            ResetState(health);
            return health;
        }

        /// <summary>Set every health of a state back to 1, as <see cref="NewState"/> without allocating.</summary>
        public void ResetState(double[] health)
        {
            for (int m = 0; m < health.Length; m++)
                health[m] = 1.0;
        }

        /// <summary>Ok when <paramref name="health"/> is a state of this file: e values in [0, 1] (NaN is not); else State.</summary>
        public FractureStatus CheckState(double[] health)
        {
            if (health == null)
                return FractureStatus.Argument;
            if (health.Length != Edges)
                return FractureStatus.State;
            foreach (double h in health)
                if (!(h >= 0.0 && h <= 1.0))
                    return FractureStatus.State;
            return FractureStatus.Ok;
        }

        /// <summary>A state as a game saves it: e little-endian doubles (8 e bytes), for any machine and reader.</summary>
        public static byte[] StateToBytes(double[] health)
        {
            if (health == null)
                throw new ArgumentNullException("health");
            var bytes = new byte[8 * health.Length];
            for (int m = 0; m < health.Length; m++)
            {
                long bits = BitConverter.DoubleToInt64Bits(health[m]);
                for (int b = 0; b < 8; b++)
                    bytes[8 * m + b] = (byte)(bits >> (8 * b));
            }
            return bytes;
        }

        /// <summary>
        /// A saved state (<see cref="StateToBytes"/>) into <paramref name="health"/> (e entries), checked: State, with
        /// <paramref name="health"/> untouched, for another size or values outside [0, 1].
        /// </summary>
        public FractureStatus StateFromBytes(byte[] bytes, double[] health)
        {
            if (bytes == null || health == null)
                return FractureStatus.Argument;
            if (bytes.Length != 8L * Edges || health.Length != Edges)
                return FractureStatus.State;
            for (int m = 0; m < Edges; m++) // all checked before any is written
            {
                double h = ReadDouble(bytes, 8 * m);
                if (!(h >= 0.0 && h <= 1.0))
                    return FractureStatus.State;
            }
            for (int m = 0; m < Edges; m++)
                health[m] = ReadDouble(bytes, 8 * m);
            return FractureStatus.Ok;
        }

        static double ReadDouble(byte[] bytes, int at)
        {
            long bits = 0;
            for (int b = 7; b >= 0; b--)
                bits = bits << 8 | bytes[at + b];
            return BitConverter.Int64BitsToDouble(bits);
        }

        /// <summary>
        /// One hit on an object whose damage state is <paramref name="health"/> (docs/FORMAT.md section 12.4),
        /// updated in place; arguments and answers as <see cref="Project"/>. Every bond the hit loads above the
        /// crack level c times its limit is cracked and loses q (load - c) of its health (q = r / (1 - c); load =
        /// its measure over its limit, 1 = at its strength); above its limit it breaks (health 0). Broken then
        /// holds every broken bond (this hit's and earlier ones'), Cracked the bonds that hold but were loaded
        /// above c by this hit or weakened before, and the groups are those of the bonds that hold; Anchored says
        /// which fragments stay held by the world (bonds to it never break). Refused hits leave the state as it
        /// was: Input as Project, State for an invalid state. On a file without feature "damage" a state only
        /// remembers broken bonds (c = 1, r = 0). Does not allocate.
        /// </summary>
        public FractureStatus Hit(double[] health, double px, double py, double pz, double nx, double ny, double nz,
                                  double threshold, FractureImpact result)
        {
            if (result == null || result.Owner != this || health == null)
                return FractureStatus.Argument;
            if (!IsFinite(px) || !IsFinite(py) || !IsFinite(pz) || !IsFinite(nx) || !IsFinite(ny) || !IsFinite(nz))
                return FractureStatus.Input;
            if (double.IsNaN(threshold) || threshold < 0)
                return FractureStatus.Input;
            FractureStatus status = CheckState(health);
            if (status != FractureStatus.Ok) // before any change: a refused hit leaves the state as it was
                return status;
            HitCore(health, px, py, pz, nx, ny, nz, threshold, result);
            return FractureStatus.Ok;
        }

        void HitCore(double[] health, double px, double py, double pz, double nx, double ny, double nz, double threshold,
                     FractureImpact result)
        {
            double m = Math.Max(Math.Abs(nx), Math.Max(Math.Abs(ny), Math.Abs(nz))), t = 0, length = 0;
            double[] alpha = result.ScaledAlpha, disp = result.ScaledDisp;
            byte[] cut = result.Cut;
            bool haveDisp = false;
            result.Site = NearestSiteCore(px, py, pz, result.KdIds, result.KdBounds);
            Array.Clear(cut, 0, Edges);
            if (m == 0) // step 1: nothing changes
            {
                Array.Clear(alpha, 0, Modes);
            }
            else
            {
                double n0 = nx / m, n1 = ny / m, n2 = nz / m;
                t = threshold / m;
                length = Math.Sqrt(n0 * n0 + n1 * n1 + n2 * n2);
                ModeCoefficients(result.Site, n0, n1, n2, length, alpha);
                if (bondPtr != null)
                {
                    StressDamage(result.Site, n0, n1, n2, t, cut, health);
                }
                else if (jumps != null)
                {
                    TableDamage(result.Site, length, t, cut, health);
                }
                else
                {
                    Displacements(alpha, disp);
                    haveDisp = true;
                    DirectDamage(disp, t, cut, health);
                }
            }
            result.NumGroups = DamageAnswers(result.Site, length, t, health, result);
            if (result.ComputeDisplacement)
            {
                if (!haveDisp)
                    Displacements(alpha, disp);
                for (int i = 0; i < disp.Length; i++)
                    result.Displacement[i] = m * disp[i];
            }
            for (int i = 0; i < Modes; i++)
                result.Alpha[i] = m * alpha[i];
            AnchoredGroups(result);
        }

        // Section 12.4 step 3 for one bond whose measure a exceeds c times its limit b (now cracked; a bond at or
        // below that keeps its health, and a > b implies it): a > b breaks it (health 0), otherwise it loses
        // q (a / b - c), never going below 0. A broken bond stays broken.
        void CrackBond(double[] health, byte[] cut, int m, double a, double b)
        {
            double h = health[m];
            cut[m] = 1;
            if (h > 0)
            {
                if (a > b)
                    h = 0;
                else
                    h = h - damageQ * (a / b - CrackLevel); // 0 < b < inf here: a / b is finite
                health[m] = h < 0 ? 0 : h;
            }
        }

        // Criterion "stress": a = g for the bonds the site lists (0, never cracked, for the others), b = t S.
        void StressDamage(int site, double n0, double n1, double n2, double t, byte[] cut, double[] health)
        {
            for (int j = bondPtr[site]; j < bondPtr[site + 1]; j++)
            {
                int e = bondEdge[j];
                double g = (double)bondGain[3 * j] * n0 + (double)bondGain[3 * j + 1] * n1 + (double)bondGain[3 * j + 2] * n2;
                double b = t * (double)bondStrength[e];
                if (g > CrackLevel * b)
                    CrackBond(health, cut, e, g, b);
            }
        }

        // Criterion "modes" with the jump table (d = 1): a = |n'| |J[v, m]|, b = t. The bonds with a <= c t are a
        // prefix of the site's row (as for t in TableHolding): only the rest crack.
        void TableDamage(int site, double length, double t, byte[] cut, double[] health)
        {
            long row = (long)site * Edges;
            for (int pos = TableHolding(site, length, CrackLevel * t); pos < Edges; pos++)
                CrackBond(health, cut, jumpEdge[row + pos], length * jumps[row + pos], t);
        }

        // Criterion "modes" from the displacements: a = |jump'| (section 4 step 5), b = t.
        void DirectDamage(double[] disp, double t, byte[] cut, double[] health)
        {
            double ct = CrackLevel * t;
            for (int m = 0; m < Edges; m++)
            {
                double a = EdgeJump(disp, m);
                if (a > ct)
                    CrackBond(health, cut, m, a, t);
            }
        }

        // Section 12.4 step 4 after every bond is updated: Broken = health <= 0, Cracked = holds and (cracked by
        // this hit or health < 1), then the groups over the bonds that hold. With the jump table the bonds that
        // hold all lie in the prefix of the site's row that this hit leaves standing; when none of the merges
        // done in that prefix is broken (by an earlier hit or by cracks), the other broken bonds of the prefix
        // only close cycles and the groups are the merges' (as in TableGroups). Otherwise a union-find.
        int DamageAnswers(int site, double length, double t, double[] health, FractureImpact result)
        {
            byte[] cut = result.Cut;
            bool[] broken = result.Broken, cracked = result.Cracked;
            int brokenCount = 0, crackedCount = 0;
            for (int m = 0; m < Edges; m++)
            {
                bool isBroken = health[m] <= 0, isCracked = !isBroken && (cut[m] != 0 || health[m] < 1);
                broken[m] = isBroken;
                cracked[m] = isCracked;
                brokenCount += isBroken ? 1 : 0;
                crackedCount += isCracked ? 1 : 0;
            }
            result.NumBroken = brokenCount;
            result.NumCracked = crackedCount;
            if (brokenCount == 0)
            {
                Array.Copy(whole, result.Groups, Fragments);
                return wholeGroups;
            }
            if (jumps != null)
            {
                int done = MergesDone(site, TableHolding(site, length, t)), r = 0;
                long row = (long)site * Edges, at = (long)site * Fragments;
                while (r < done && health[jumpEdge[row + mergeAt[at + r]]] > 0)
                    r++;
                if (r == done)
                    return MergeGroups(site, done, result.Labels, result.Groups);
            }
            int[] uf = result.Labels;
            Array.Copy(identity, uf, Fragments);
            for (int m = 0; m < Edges; m++)
                if (!broken[m])
                    Unite(uf, edges[2 * m], edges[2 * m + 1]);
            return Label(uf, Fragments, result.Groups);
        }

        // ------------------------------------------------------------------ header

        // ------------------------------------------------------------------ levels (docs/FORMAT.md section 14)
        //
        // A body is a set of fragments (its children) with its own impact data: body 0 is this runtime (the p
        // level-1 fragments), body b >= 1 breaks fragment BodyFragment(b) into fragments BodyFirst(b) ..
        // BodyFirst(b + 1) - 1 (global indices over every level). Body(b) is body b's view, a runtime of its own
        // (loaded and checked as a file), on which Project and Hit run in local indices. An object state is one
        // double[] of every body's bond healths; HitPiece hits the piece holding a shown fragment (section 14.5)
        // and ObjectPieces lists the rigid bodies a game shows (section 14.4). These allocate (a few small arrays
        // per call), unlike Project and Hit.

        static readonly string[] LevelArrays = { "parent", "body_fragment", "body_child_ptr", "body_site_ptr", "body_sites",
            "body_B", "body_W", "body_edge_ptr", "body_edges", "body_edge_areas", "body_site_bonds_ptr", "body_site_bonds",
            "body_site_bond_gain", "body_bond_strength", "body_crack_ptr", "body_crack_segments" };
        static readonly int[] LevelRanks = { 1, 1, 1, 1, 2, 3, 3, 1, 2, 1, 1, 1, 2, 1, 1, 3 };
        static readonly bool[] LevelIsInt = { true, true, true, true, false, false, false, true, true, false, true, true, false,
            false, true, false };

        int[] lvParent, lvBodyFragment, lvChildPtr, lvStateOffsets, lvBodyOf, lvHolding;
        FractureRuntime[] lvViews;
        string[] childNames;

        /// <summary>Bodies in the file (1 without levels, body 0 included).</summary>
        public int NumBodies { get { return lvViews != null ? lvViews.Length : 1; } }
        /// <summary>Fragments of every level (p_all; p without levels).</summary>
        public int AllFragments { get { return lvParent != null ? lvParent.Length : Fragments; } }
        /// <summary>The deepest level (1 without levels).</summary>
        public int LevelCount { get; private set; }
        /// <summary>Body b's view (body 0: this runtime), or null.</summary>
        public FractureRuntime Body(int b) { return b == 0 ? this : lvViews != null && b > 0 && b < lvViews.Length ? lvViews[b] : null; }
        /// <summary>The fragment body b breaks (-1 for body 0).</summary>
        public int BodyFragment(int b) { return lvBodyFragment != null && b > 0 ? lvBodyFragment[b] : -1; }
        /// <summary>Body b's first child (global); BodyFirst(NumBodies) is AllFragments.</summary>
        public int BodyFirst(int b) { return lvChildPtr != null ? lvChildPtr[b] : b == 0 ? 0 : Fragments; }
        /// <summary>The body breaking fragment g into its children, -1 for a leaf.</summary>
        public int BodyOf(int g) { return lvBodyOf != null ? lvBodyOf[g] : -1; }
        /// <summary>The body whose child fragment g is (0 at level 1).</summary>
        public int BodyHolding(int g) { return lvHolding != null ? lvHolding[g] : 0; }
        /// <summary>Fragment g's parent, -1 at level 1.</summary>
        public int Parent(int g) { return lvParent != null ? lvParent[g] : -1; }
        /// <summary>The GLB node name of fragment g (any level).</summary>
        public string AnyFragmentName(int g) { return g < Fragments ? names[g] : childNames[g - Fragments]; }
        /// <summary>Where body b's healths start in an object state.</summary>
        public int StateOffset(int b) { return lvStateOffsets != null ? lvStateOffsets[b] : b == 0 ? 0 : Edges; }

        static bool PtrOk(int[] ptr, int first, long end)
        {
            if (ptr[0] != first || ptr[ptr.Length - 1] != end)
                return false;
            for (int i = 1; i < ptr.Length; i++)
                if (ptr[i] < ptr[i - 1])
                    return false;
            return true;
        }

        static string JsonString(string value)
        {
            var text = new StringBuilder("\"");
            foreach (char c in value)
            {
                if (c == '"' || c == '\\')
                    text.Append('\\').Append(c);
                else if (c < 0x20)
                    text.Append("\\u").Append(((int)c).ToString("x4", CultureInfo.InvariantCulture));
                else
                    text.Append(c);
            }
            return text.Append('"').ToString();
        }

        static string Number(double value) { return value.ToString("G17", CultureInfo.InvariantCulture); }

        void ReadLevels(Header h, byte[] binary, bool compact)
        {
            bool stress = h.Stress, cracks = false;
            object value;
            var table = h.Top["arrays"] as Dictionary<string, object>;
            var entries = new ArrayEntry[LevelArrays.Length];
            for (int i = 0; i < LevelArrays.Length; i++)
                if (table.TryGetValue(LevelArrays[i], out value) && value is Dictionary<string, object>)
                    entries[i] = Header.ReadEntry((Dictionary<string, object>)value);
            cracks = table.ContainsKey("body_crack_ptr") || table.ContainsKey("body_crack_segments");
            var ints = new int[LevelArrays.Length][];
            var floats = new float[LevelArrays.Length][];
            for (int i = 0; i < LevelArrays.Length; i++)
            {
                if ((i >= 10 && i < 14 && !stress) || (i >= 14 && !cracks))
                    continue;
                Header.CheckEntry(entries[i], LevelArrays[i], LevelIsInt[i], LevelRanks[i], binary.LongLength);
                if (LevelIsInt[i])
                    ints[i] = ReadInts(binary, entries[i]);
                else
                    floats[i] = ReadFloats(binary, entries[i], LevelArrays[i]);
            }
            int p = Fragments, d = Dim;
            int[] parent = ints[0], owner = ints[1], child = ints[2], sitePtr = ints[3], edgePtr = ints[7];
            int pAll = parent.Length, nb = owner.Length, C = pAll - p;
            long S = entries[4].Shape[0], K = entries[5].Shape[1], E = entries[8].Shape[0];
            var counts = h.Top["counts"] as Dictionary<string, object>;
            Func<string, long> count = key => { long got; return counts.TryGetValue(key, out value) && Json.AsInteger(value, out got) ? got : -1; };
            if (count("bodies") != nb || count("all_fragments") != pAll || count("body_sites") != S || count("body_modes") != K ||
                count("body_edges") != E)
                throw Fail(FractureStatus.Size, "header counts of the levels arrays do not match the arrays");
            if (pAll <= p || nb < 2)
                throw Fail(FractureStatus.Size, "a file with levels has more fragments than level 1 and at least two bodies");
            var info = h.Top.TryGetValue("levels", out value) ? value as Dictionary<string, object> : null;
            if (info == null)
                throw Fail(FractureStatus.Header, "the feature 'levels' needs a header object 'levels'");
            var nameList = h.Top.TryGetValue("child_names", out value) ? value as List<object> : null;
            if (nameList == null || nameList.Count != C || nameList.Exists(n => !(n is string)))
                throw Fail(FractureStatus.Header, "child_names must be " + C + " strings");
            Func<int, long[], bool> same = (i, shape) =>
            {
                if (entries[i].Shape.Length != shape.Length)
                    return false;
                for (int r = 0; r < shape.Length; r++)
                    if (entries[i].Shape[r] != shape[r])
                        return false;
                return true;
            };
            if (!same(2, new long[] { nb + 1 }) || !same(3, new long[] { nb + 1 }) || !same(7, new long[] { nb + 1 }) ||
                !same(4, new long[] { S, 3 }) || K < 1 || !same(5, new long[] { S, K, d }) || !same(6, new long[] { K, C, d }) ||
                !same(8, new long[] { E, 2 }) || !same(9, new long[] { E }))
                throw Fail(FractureStatus.Size, "levels array shapes do not agree with each other");
            long N = stress ? entries[11].Shape[0] : 0, segments = cracks ? entries[15].Shape[0] : 0;
            if (stress && (!same(10, new long[] { S + 1 }) || !same(12, new long[] { N, 3 }) || !same(13, new long[] { E }) ||
                           count("body_site_bonds") != N))
                throw Fail(FractureStatus.Size, "levels stress arrays do not agree with each other or counts");
            if (cracks && (!same(14, new long[] { E + 1 }) || !same(15, new long[] { segments, 2, 3 }) ||
                           count("body_crack_segments") != segments))
                throw Fail(FractureStatus.Size, "levels crack arrays do not agree with each other or counts");
            var level = new int[pAll];
            int deepest = 1;
            for (int g = 0; g < pAll; g++)
            {
                if (g < p ? parent[g] != -1 : !(parent[g] >= 0 && parent[g] < g))
                    throw Fail(FractureStatus.Data, "parent must be -1 for the level-1 fragments and a smaller fragment index for every other");
                level[g] = parent[g] < 0 ? 1 : level[parent[g]] + 1;
                deepest = Math.Max(deepest, level[g]);
            }
            bool ok = owner[0] == -1 && owner[1] >= 0 && owner[nb - 1] < pAll;
            for (int b = 2; ok && b < nb; b++)
                ok = owner[b] > owner[b - 1];
            if (!ok)
                throw Fail(FractureStatus.Data, "body_fragment must be -1 for body 0, then fragment indices strictly increasing");
            if (!PtrOk(child, 0, pAll) || child[1] != p)
                throw Fail(FractureStatus.Data, "body_child_ptr must start at 0, then " + p + ", and end at " + pAll);
            for (int b = 0; b < nb; b++)
                if (child[b + 1] - child[b] < 2)
                    throw Fail(FractureStatus.Data, "every body must have at least 2 children (body " + b + ")");
            for (int b = 1; b < nb; b++)
                for (int g = child[b]; g < child[b + 1]; g++)
                    if (parent[g] != owner[b])
                        throw Fail(FractureStatus.Data, "parent of every child must be the fragment of the body that holds it");
            if (!PtrOk(sitePtr, 0, S) || !PtrOk(edgePtr, 0, E) || sitePtr[1] != 0 || edgePtr[1] != 0)
                throw Fail(FractureStatus.Data, "body_site_ptr and body_edge_ptr must start at 0 (body 0 has no rows) and end at their arrays' lengths");
            for (int b = 1; b < nb; b++)
                if (sitePtr[b + 1] <= sitePtr[b])
                    throw Fail(FractureStatus.Data, "body " + b + " has no sites");
            if (stress && !PtrOk(ints[10], 0, N))
                throw Fail(FractureStatus.Data, "body_site_bonds_ptr must start at 0, never decrease and end at N");
            if (cracks && !PtrOk(ints[14], 0, segments))
                throw Fail(FractureStatus.Data, "body_crack_ptr must start at 0, never decrease and end at n");
            for (int b = 1; b < nb; b++)
                if (anchored != null && owner[b] < p && anchored[owner[b]] == 1)
                    throw Fail(FractureStatus.Data, "an anchored fragment cannot be broken further (it has a body)");
            long levelCount;
            if (!info.TryGetValue("count", out value) || !Json.AsInteger(value, out levelCount) || levelCount != deepest)
                throw Fail(FractureStatus.Header, "levels.count must be the deepest level, " + deepest);
            var thresholdList = info.TryGetValue("thresholds", out value) ? value as List<object> : null;
            var thresholds = new double[deepest];
            if (thresholdList == null || thresholdList.Count != deepest)
                throw Fail(FractureStatus.Header, "levels.thresholds must list " + deepest + " finite numbers >= 0, one per level");
            for (int i = 0; i < deepest; i++)
                if (!Json.AsNumber(thresholdList[i], out thresholds[i]) || !IsFinite(thresholds[i]) || thresholds[i] < 0)
                    throw Fail(FractureStatus.Header, "levels.thresholds must list " + deepest + " finite numbers >= 0, one per level");
            if (thresholds[0] != DefaultThreshold)
                throw Fail(FractureStatus.Header, "levels.thresholds[0] must be default_threshold");
            var radiusList = info.TryGetValue("impact_radii", out value) ? value as List<object> : null;
            LevelCount = deepest;
            lvParent = parent;
            lvBodyFragment = owner;
            lvChildPtr = child;
            lvBodyOf = new int[pAll];
            lvHolding = new int[pAll];
            lvStateOffsets = new int[nb + 1];
            childNames = new string[C];
            for (int c = 0; c < C; c++)
                childNames[c] = (string)nameList[c];
            for (int g = 0; g < pAll; g++)
                lvBodyOf[g] = -1;
            for (int b = 1; b < nb; b++)
            {
                lvBodyOf[owner[b]] = b;
                for (int g = child[b]; g < child[b + 1]; g++)
                    lvHolding[g] = b;
                lvStateOffsets[b] = Edges + edgePtr[b];
            }
            lvStateOffsets[nb] = Edges + (int)E;
            var views = new FractureRuntime[nb];
            views[0] = this;
            for (int b = 1; b < nb; b++)
            {
                int bodyLevel = level[owner[b]] + 1;
                double radius = ImpactRadius, r;
                if (radiusList != null && radiusList.Count >= bodyLevel && Json.AsNumber(radiusList[bodyLevel - 1], out r))
                    radius = r;
                views[b] = MakeView(b, ints, floats, (int)K, C, stress, cracks, thresholds[bodyLevel - 1], radius, compact, h);
            }
            lvViews = views;
        }

        FractureRuntime MakeView(int b, int[][] ints, float[][] floats, int K, int C, bool stress, bool cracks, double threshold,
                                 double radius, bool compact, Header h)
        {
            int p = Fragments, d = Dim;
            int s0 = ints[3][b], s1 = ints[3][b + 1], g0 = ints[2][b] - p, g1 = ints[2][b + 1] - p, e0 = ints[7][b], e1 = ints[7][b + 1];
            int sb = s1 - s0, cb = g1 - g0, eb = e1 - e0;
            var arrays = new List<KeyValuePair<string, object>>(); // name -> (int[] or float[], shape)
            var shapes = new List<long[]>();
            Action<string, object, long[]> add = (name, values, shape) =>
            {
                arrays.Add(new KeyValuePair<string, object>(name, values));
                shapes.Add(shape);
            };
            var W = new float[K * cb * d];
            for (int k = 0; k < K; k++)
                Array.Copy(floats[6], (k * C + g0) * d, W, k * cb * d, cb * d);
            add("sites", Slice(floats[4], 3 * s0, 3 * sb), new long[] { sb, 3 });
            add("B", Slice(floats[5], s0 * K * d, sb * K * d), new long[] { sb, K, d });
            add("W", W, new long[] { K, cb, d });
            add("edges", Slice(ints[8], 2 * e0, 2 * eb), new long[] { eb, 2 });
            add("edge_areas", Slice(floats[9], e0, eb), new long[] { eb });
            var counts = new StringBuilder();
            counts.Append("\"sites\":" + sb + ",\"modes\":" + K + ",\"fragments\":" + cb + ",\"edges\":" + eb);
            if (stress)
            {
                int n0 = ints[10][s0], n1 = ints[10][s1];
                var ptr = Slice(ints[10], s0, sb + 1);
                for (int i = 0; i < ptr.Length; i++)
                    ptr[i] -= n0;
                add("site_bonds_ptr", ptr, new long[] { sb + 1 });
                add("site_bonds", Slice(ints[11], n0, n1 - n0), new long[] { n1 - n0 });
                add("site_bond_gain", Slice(floats[12], 3 * n0, 3 * (n1 - n0)), new long[] { n1 - n0, 3 });
                add("bond_strength", Slice(floats[13], e0, eb), new long[] { eb });
                counts.Append(",\"site_bonds\":" + (n1 - n0));
            }
            if (cracks)
            {
                int c0 = ints[14][e0], c1 = ints[14][e1];
                var ptr = Slice(ints[14], e0, eb + 1);
                for (int i = 0; i < ptr.Length; i++)
                    ptr[i] -= c0;
                add("crack_ptr", ptr, new long[] { eb + 1 });
                add("crack_segments", Slice(floats[15], 6 * c0, 6 * (c1 - c0)), new long[] { c1 - c0, 2, 3 });
                counts.Append(",\"crack_segments\":" + (c1 - c0));
            }
            long size = 0;
            var table = new StringBuilder();
            var offsets = new long[arrays.Count];
            for (int i = 0; i < arrays.Count; i++)
            {
                int length = arrays[i].Value is int[] ? ((int[])arrays[i].Value).Length : ((float[])arrays[i].Value).Length;
                offsets[i] = size;
                table.Append((i > 0 ? "," : "") + JsonString(arrays[i].Key) + ":{\"dtype\":\"" + (arrays[i].Value is int[] ? "int32" : "float32") +
                             "\",\"byte_offset\":" + size + ",\"byte_length\":" + 4 * length + ",\"shape\":[" +
                             string.Join(",", Array.ConvertAll(shapes[i], x => x.ToString(CultureInfo.InvariantCulture))) + "]}");
                size += (4L * length + 15) / 16 * 16;
            }
            var bytes = new byte[size];
            for (int i = 0; i < arrays.Count; i++)
            {
                var bits = new Bits32();
                var asInts = arrays[i].Value as int[];
                var asFloats = arrays[i].Value as float[];
                int length = asInts != null ? asInts.Length : asFloats.Length;
                for (int j = 0; j < length; j++)
                {
                    if (asInts != null)
                        bits.Int = asInts[j];
                    else
                        bits.Float = asFloats[j];
                    for (int c = 0; c < 4; c++)
                        bytes[offsets[i] + 4 * j + c] = (byte)(bits.Int >> (8 * c));
                }
            }
            var features = new List<string>();
            if (stress)
                features.Add("\"stress\"");
            if (HasDamage)
                features.Add("\"damage\"");
            var names = new string[cb];
            for (int c = 0; c < cb; c++)
                names[c] = JsonString(childNames[g0 + c]);
            string text = "{\"format\":\"fracture-modes-runtime\",\"version\":2,\"features\":[" + string.Join(",", features.ToArray()) +
                          "],\"criterion\":\"" + Criterion + "\",\"dim\":" + d + ",\"counts\":{" + counts + "},\"fragment_names\":[" +
                          string.Join(",", names) + "],\"transform\":[" + string.Join(",", Array.ConvertAll(transform, Number)) +
                          "],\"default_threshold\":" + Number(threshold) + ",\"impact_radius\":" + Number(radius) +
                          (HasDamage ? ",\"damage\":{\"crack_level\":" + Number(CrackLevel) + ",\"damage_rate\":" + Number(DamageRate) + "}" : "") +
                          ",\"buffer\":{\"uri\":\"view.fracture.bin\",\"byte_length\":" + size + "},\"arrays\":{" + table + "}}";
            try
            {
                return new FractureRuntime(Header.Parse(Encoding.UTF8.GetBytes(text), true), bytes, false, compact);
            }
            catch (FractureRuntimeException exception)
            {
                throw Fail(exception.Status, "body " + b + ": " + exception.Message);
            }
        }

        static T[] Slice<T>(T[] source, int start, int length)
        {
            var out_ = new T[length];
            Array.Copy(source, start, out_, 0, length);
            return out_;
        }

        /// <summary>A fresh object state (section 14.4): every body's bond healths, all 1.</summary>
        public double[] NewObjectState()
        {
            var state = new double[StateOffset(NumBodies)];
            for (int i = 0; i < state.Length; i++)
                state[i] = 1.0;
            return state;
        }

        /// <summary>Ok when <paramref name="state"/> holds e + E healths in [0, 1]; else State.</summary>
        public FractureStatus CheckObjectState(double[] state)
        {
            if (state == null)
                return FractureStatus.Argument;
            if (state.Length != StateOffset(NumBodies))
                return FractureStatus.State;
            foreach (double h in state)
                if (!(h >= 0.0 && h <= 1.0))
                    return FractureStatus.State;
            return FractureStatus.Ok;
        }

        // Groups (smallest local index) of body b's children over bonds with health > 0 between two kept children.
        int[] BodyGroups(double[] state, int b, bool[] keep)
        {
            FractureRuntime view = Body(b);
            int offset = StateOffset(b);
            var groups = (int[])view.identity.Clone();
            for (int m = 0; m < view.Edges; m++)
            {
                int P = view.edges[2 * m], Q = view.edges[2 * m + 1];
                if (state[offset + m] > 0 && (keep == null || (keep[P] && keep[Q])))
                    Unite(groups, P, Q);
            }
            Label(groups, view.Fragments, groups);
            return groups;
        }

        static int CountRoots(int[] groups)
        {
            int count = 0;
            for (int j = 0; j < groups.Length; j++)
                count += groups[j] == j ? 1 : 0;
            return count;
        }

        /// <summary>Whether fragment g broke into its children (its body's unbroken bonds leave two or more groups).</summary>
        public bool IsSplit(double[] state, int g)
        {
            int b = BodyOf(g);
            return b >= 0 && CountRoots(BodyGroups(state, b, null)) >= 2;
        }

        bool Opened(double[] state, int g)
        {
            for (int a = Parent(g); a >= 0; a = Parent(a))
                if (!IsSplit(state, a))
                    return false;
            return true;
        }

        /// <summary>Whether fragment g is shown: not split, every ancestor split.</summary>
        public bool IsShown(double[] state, int g)
        {
            return g >= 0 && g < AllFragments && !IsSplit(state, g) && Opened(state, g);
        }

        bool[] ShownChildren(double[] state, int b)
        {
            int first = BodyFirst(b);
            var keep = new bool[Body(b).Fragments];
            for (int j = 0; j < keep.Length; j++)
                keep[j] = !IsSplit(state, first + j);
            return keep;
        }

        List<FracturePiece> PiecesOf(double[] state, int b, bool[] keep)
        {
            int[] groups = BodyGroups(state, b, keep);
            int first = BodyFirst(b);
            var pieces = new List<FracturePiece>();
            var byRoot = new Dictionary<int, FracturePiece>();
            for (int j = 0; j < groups.Length; j++) // by smallest member: a group's root comes first
            {
                if (!keep[j])
                    continue;
                FracturePiece piece;
                if (!byRoot.TryGetValue(groups[j], out piece))
                {
                    byRoot[groups[j]] = piece = new FracturePiece(b);
                    pieces.Add(piece);
                }
                piece.Fragments.Add(first + j);
                if (b == 0 && anchored != null && anchored[j] == 1)
                    piece.Anchored = true;
            }
            return pieces;
        }

        /// <summary>Every piece of the object (section 14.4): body by body, each by its first fragment.</summary>
        public List<FracturePiece> ObjectPieces(double[] state)
        {
            if (CheckObjectState(state) != FractureStatus.Ok)
                throw new ArgumentException("not an object state of this runtime file");
            var pieces = new List<FracturePiece>();
            for (int b = 0; b < NumBodies; b++)
                if (b == 0 || (IsSplit(state, BodyFragment(b)) && Opened(state, BodyFragment(b))))
                    pieces.AddRange(PiecesOf(state, b, ShownChildren(state, b)));
            return pieces;
        }

        /// <summary>
        /// Hit the piece holding the shown fragment <paramref name="struck"/> (docs/FORMAT.md section 14.5): point and
        /// impulse in the asset's model space, threshold null for each body's default. <paramref name="state"/> (an
        /// object state) is updated in place and left as it was when the hit is refused (Input, State, Fragment).
        /// </summary>
        public FractureStatus HitPiece(double[] state, int struck, double px, double py, double pz, double nx, double ny,
                                       double nz, double? threshold, out FracturePieceHit hit)
        {
            hit = null;
            FractureStatus status = CheckObjectState(state);
            if (status != FractureStatus.Ok)
                return status;
            if (!IsShown(state, struck))
                return FractureStatus.Fragment;
            int b = BodyHolding(struck), first = BodyFirst(b), offset = StateOffset(b);
            FractureRuntime view = Body(b);
            bool[] keep = ShownChildren(state, b);
            int[] before = BodyGroups(state, b, keep);
            var inside = new bool[keep.Length];
            for (int j = 0; j < keep.Length; j++)
                inside[j] = keep[j] && before[j] == before[struck - first];
            var trial = new double[view.Edges];
            Array.Copy(state, offset, trial, 0, view.Edges);
            var result = new FractureImpact(view);
            status = view.Hit(trial, px, py, pz, nx, ny, nz, threshold ?? view.DefaultThreshold, result);
            if (status != FractureStatus.Ok) // inputs refused before anything changed
                return status;
            result.NumBroken = result.NumCracked = 0;
            for (int m = 0; m < view.Edges; m++)
            {
                bool within = inside[view.edges[2 * m]] && inside[view.edges[2 * m + 1]];
                if (within)
                    state[offset + m] = trial[m];
                result.Broken[m] = state[offset + m] <= 0;
                result.Cracked[m] = !result.Broken[m] && ((result.Cracked[m] && within) || state[offset + m] < 1);
                result.NumBroken += result.Broken[m] ? 1 : 0;
                result.NumCracked += result.Cracked[m] ? 1 : 0;
            }
            int[] groups = BodyGroups(state, b, null);
            Array.Copy(groups, result.Groups, groups.Length);
            result.NumGroups = CountRoots(groups);
            view.AnchoredGroups(result);
            int childBody = BodyOf(struck);
            FractureImpact childResult = null;
            bool split = false;
            if (childBody >= 0)
            {
                FractureRuntime childView = Body(childBody);
                var health = new double[childView.Edges];
                int childOffset = StateOffset(childBody);
                Array.Copy(state, childOffset, health, 0, health.Length);
                childResult = new FractureImpact(childView);
                childView.Hit(health, px, py, pz, nx, ny, nz, threshold ?? childView.DefaultThreshold, childResult);
                Array.Copy(health, 0, state, childOffset, health.Length);
                split = childResult.NumGroups >= 2;
            }
            if (split)
                inside[struck - first] = false;
            List<FracturePiece> pieces = PiecesOf(state, b, inside);
            if (split)
                pieces.AddRange(PiecesOf(state, childBody, ShownChildren(state, childBody)));
            hit = new FracturePieceHit(struck, b, result, childBody, childResult, split, pieces);
            return FractureStatus.Ok;
        }

        internal sealed class ArrayEntry
        {
            public string DType;
            public long[] Shape;
            public long Offset = -1, Length = -1;
            public bool ShapeOk = true;
        }

        // The five arrays of section 2, the four of the stress criterion (section 11, with feature "stress"), then
        // those of section 12: anchored (feature "anchors") and the optional crack arrays (version 2).
        static readonly string[] ArrayNames = { "sites", "B", "W", "edges", "edge_areas", "site_bonds_ptr", "site_bonds",
                                                "site_bond_gain", "bond_strength", "anchored", "crack_ptr",
                                                "crack_segments" };
        static readonly int[] ArrayRanks = { 2, 3, 3, 2, 1, 1, 1, 2, 1, 1, 1, 3 };
        static readonly bool[] ArrayIsInt = { false, false, false, true, false, true, true, false, false, true, true,
                                              false };

        internal sealed class Header
        {
            public bool HasDim, HasThreshold, HasRadius, HasTransform, HasLength, HasCrc, HasBuffer, HasArrays;
            public bool Stress; // version 2 with feature "stress" and criterion "stress"
            public bool Anchors, Damage; // version 2 with feature "anchors", "damage"
            public bool Cracks; // version 2 whose table lists crack_ptr or crack_segments
            public bool Levels, IsView; // feature "levels"; a body's view made by this reader (no features needed)
            public Dictionary<string, object> Top; // the whole header (the levels keys are read by ReadLevels)
            public object DamageObject; // the header's "damage" value (checked by CheckDamage)
            public double CrackLevel, DamageRate;
            public long Dim, ByteLength, Crc, SiteBondsCount = -1, CrackSegmentsCount = -1;
            public long[] Counts;
            public string[] Names;
            public string Uri;
            public double DefaultThreshold, ImpactRadius;
            public readonly double[] Transform = new double[16];
            public readonly ArrayEntry[] Arrays = new ArrayEntry[12];

            public static Header Parse(byte[] bytes, bool isView = false)
            {
                string text;
                try
                {
                    text = new UTF8Encoding(false, true).GetString(bytes);
                }
                catch (ArgumentException)
                {
                    throw Fail(FractureStatus.Json, "header is not UTF-8");
                }
                object root = new Json(text).ParseDocument();
                var top = root as Dictionary<string, object>;
                if (top == null)
                    throw Fail(FractureStatus.Json, "header is not a JSON object");
                object value;
                if (!top.TryGetValue("format", out value) || !"fracture-modes-runtime".Equals(value))
                    throw Fail(FractureStatus.Format, "not a fracture runtime file (expected \"format\": \"fracture-modes-runtime\")");
                long version;
                if (!top.TryGetValue("version", out value) || !Json.AsInteger(value, out version) || version < 1 ||
                    version > FormatVersion)
                    throw Fail(FractureStatus.Format, "runtime file version is not supported (this reader knows 1.." +
                                                      FormatVersion + ")");
                var h = new Header();
                List<object> features = CheckFeatures(top, version, isView);
                h.Levels = features.Contains("levels");
                h.IsView = isView;
                h.Top = top;
                h.Stress = features.Contains("stress");
                h.Anchors = features.Contains("anchors");
                h.Damage = features.Contains("damage");
                if (h.Damage)
                    top.TryGetValue("damage", out h.DamageObject);
                h.Read(top, version);
                return h;
            }

            // Section 11: version 2 lists the features it needs (refused by name when unknown) and a criterion;
            // version 1 ignores both keys. Like the reference reader, a file that lists "stress" must use
            // criterion "stress" (the stress arrays come with the criterion). Returns the features.
            static List<object> CheckFeatures(Dictionary<string, object> top, long version, bool isView)
            {
                if (version < 2)
                    return new List<object>();
                object value;
                var features = top.TryGetValue("features", out value) ? value as List<object> : new List<object>();
                if (features == null || features.Exists(f => !(f is string)))
                    throw Fail(FractureStatus.Header, "runtime header 'features' must be a list of strings");
                if (features.Count == 0 && !isView)
                    throw Fail(FractureStatus.Format, "runtime file version " + version +
                                                      " lists no features; a file without any is version 1");
                foreach (object feature in features)
                    if (Array.IndexOf(KnownFeatures, (string)feature) < 0)
                        throw Fail(FractureStatus.Format, "runtime file needs feature '" + feature +
                                                          "', which this reader does not implement");
                bool stress = features.Contains("stress");
                object criterion = top.TryGetValue("criterion", out value) ? value : "modes";
                if (!(criterion is string))
                    throw Fail(FractureStatus.Header, "runtime header 'criterion' must be a string");
                if ((string)criterion != "modes" && (string)criterion != "stress")
                    throw Fail(FractureStatus.Format, "runtime file needs criterion '" + criterion +
                                                      "', which this reader does not implement");
                if ((string)criterion == "stress" && !stress)
                    throw Fail(FractureStatus.Format, "runtime file has criterion 'stress' but does not list feature 'stress'");
                if ((string)criterion != "stress" && stress)
                    throw Fail(FractureStatus.Format, "runtime file lists feature 'stress' but its criterion is 'modes' " +
                                                      "(the stress arrays come with criterion 'stress')");
                return features;
            }

            // Section 12.1: with feature "damage", the object `damage` with 0 < crack_level <= 1 and a finite
            // damage_rate >= 0.
            public void CheckDamage()
            {
                var damage = DamageObject as Dictionary<string, object>;
                if (damage == null)
                    throw Fail(FractureStatus.Header, "the feature 'damage' needs a header object 'damage'");
                object value;
                if (!damage.TryGetValue("crack_level", out value) || !Json.AsNumber(value, out CrackLevel) ||
                    !IsFinite(CrackLevel))
                    throw Fail(FractureStatus.Header, "damage.crack_level must be a finite number");
                if (!damage.TryGetValue("damage_rate", out value) || !Json.AsNumber(value, out DamageRate) ||
                    !IsFinite(DamageRate))
                    throw Fail(FractureStatus.Header, "damage.damage_rate must be a finite number");
                if (!(CrackLevel > 0 && CrackLevel <= 1))
                    throw Fail(FractureStatus.Header, "damage.crack_level must be in (0, 1], got " +
                                                      CrackLevel.ToString(CultureInfo.InvariantCulture));
                if (DamageRate < 0)
                    throw Fail(FractureStatus.Header, "damage.damage_rate must be >= 0, got " +
                                                      DamageRate.ToString(CultureInfo.InvariantCulture));
            }

            void Read(Dictionary<string, object> top, long version)
            {
                object value;
                HasDim = top.TryGetValue("dim", out value) && Json.AsInteger(value, out Dim);
                HasThreshold = top.TryGetValue("default_threshold", out value) && Json.AsNumber(value, out DefaultThreshold);
                HasRadius = top.TryGetValue("impact_radius", out value) && Json.AsNumber(value, out ImpactRadius);
                var list = top.TryGetValue("transform", out value) ? value as List<object> : null;
                HasTransform = list != null && list.Count == 16;
                for (int i = 0; HasTransform && i < 16; i++)
                    HasTransform = Json.AsNumber(list[i], out Transform[i]);
                var counts = top.TryGetValue("counts", out value) ? value as Dictionary<string, object> : null;
                if (counts != null)
                {
                    string[] keys = { "sites", "modes", "fragments", "edges" };
                    Counts = new long[4];
                    for (int i = 0; i < 4 && Counts != null; i++)
                        if (!counts.TryGetValue(keys[i], out value) || !Json.AsInteger(value, out Counts[i]))
                            Counts = null;
                    if (Stress && (!counts.TryGetValue("site_bonds", out value) || !Json.AsInteger(value, out SiteBondsCount)))
                        SiteBondsCount = -1;
                    if (!counts.TryGetValue("crack_segments", out value) || !Json.AsInteger(value, out CrackSegmentsCount))
                        CrackSegmentsCount = -1;
                }
                var names = top.TryGetValue("fragment_names", out value) ? value as List<object> : null;
                if (names != null)
                {
                    Names = new string[names.Count];
                    for (int i = 0; i < names.Count && Names != null; i++)
                        if ((Names[i] = names[i] as string) == null || Names[i].IndexOf('\0') >= 0)
                            Names = null;
                }
                var buffer = top.TryGetValue("buffer", out value) ? value as Dictionary<string, object> : null;
                HasBuffer = buffer != null;
                if (HasBuffer)
                {
                    Uri = buffer.TryGetValue("uri", out value) ? value as string : null;
                    HasLength = buffer.TryGetValue("byte_length", out value) && Json.AsInteger(value, out ByteLength);
                    HasCrc = buffer.TryGetValue("crc32", out value) && Json.AsInteger(value, out Crc);
                    if (buffer.ContainsKey("crc32") && !HasCrc)
                        throw Fail(FractureStatus.Header, "buffer.crc32 must be a 32-bit unsigned integer");
                }
                var arrays = top.TryGetValue("arrays", out value) ? value as Dictionary<string, object> : null;
                HasArrays = arrays != null;
                for (int i = 0; HasArrays && i < Arrays.Length; i++)
                {
                    var entry = arrays.TryGetValue(ArrayNames[i], out value) ? value as Dictionary<string, object> : null;
                    if (entry != null)
                        Arrays[i] = ReadEntry(entry);
                }
                Cracks = HasArrays && version >= 2 && (arrays.ContainsKey("crack_ptr") || arrays.ContainsKey("crack_segments"));
            }

            // The arrays the file must hold: the required five and those of the features it lists.
            bool Needed(int i)
            {
                return i < 5 || (i < 9 ? Stress : i == 9 ? Anchors : Cracks);
            }

            internal static ArrayEntry ReadEntry(Dictionary<string, object> entry)
            {
                var a = new ArrayEntry();
                object value;
                a.DType = entry.TryGetValue("dtype", out value) ? value as string : null;
                if (entry.TryGetValue("byte_offset", out value) && !Json.AsInteger(value, out a.Offset))
                    a.Offset = -1;
                if (entry.TryGetValue("byte_length", out value) && !Json.AsInteger(value, out a.Length))
                    a.Length = -1;
                var shape = entry.TryGetValue("shape", out value) ? value as List<object> : null;
                if (shape != null)
                {
                    a.Shape = new long[shape.Count];
                    for (int i = 0; i < shape.Count; i++)
                        if (!Json.AsInteger(shape[i], out a.Shape[i]) || a.Shape[i] < 0)
                            a.ShapeOk = false;
                }
                return a;
            }

            public void CheckKeys()
            {
                string missing = !HasDim ? "dim" : Counts == null ? "counts" : Names == null ? "fragment_names"
                    : !HasTransform ? "transform (16 numbers)" : !HasThreshold ? "default_threshold"
                    : !HasRadius ? "impact_radius" : !HasBuffer ? "buffer" : !HasLength ? "buffer.byte_length"
                    : !HasArrays ? "arrays" : null;
                if (missing != null)
                    throw Fail(FractureStatus.Header, "runtime header is missing or has a malformed entry: " + missing);
            }

            public void CheckUri()
            {
                if (Uri == null || Uri.Length == 0 || Uri == "." || Uri == ".." || Uri.IndexOfAny(new[] { '/', '\\', ':', '\0' }) >= 0)
                    throw Fail(FractureStatus.Header, "buffer.uri must be a plain file name next to the header");
            }

            // One array entry: present, its dtype and rank, byte_length = 4 * product(shape), inside the file.
            internal static void CheckEntry(ArrayEntry a, string name, bool isInt, int rank, long binarySize)
            {
                if (a == null || a.DType == null || a.Shape == null)
                    throw Fail(FractureStatus.Header, "array '" + name + "' entry is missing or malformed");
                if (a.DType != (isInt ? "int32" : "float32"))
                    throw Fail(FractureStatus.Header, "array '" + name + "' has the wrong dtype");
                if (a.Shape.Length != rank)
                    throw Fail(FractureStatus.Size, "array '" + name + "' has " + a.Shape.Length + " dimensions, expected " + rank);
                if (!a.ShapeOk)
                    throw Fail(FractureStatus.Size, "array '" + name + "' has a negative or non-integer size");
                long count = 1;
                foreach (long n in a.Shape)
                    count = n != 0 && count > (1L << 40) / n ? (1L << 40) + 1 : count * n;
                if (a.Length < 0 || count * 4 != a.Length)
                    throw Fail(FractureStatus.Size, "array '" + name + "': shape and byte_length do not agree");
                if (a.Offset < 0 || a.Offset % 16 != 0 || a.Offset > binarySize || a.Length > binarySize - a.Offset)
                    throw Fail(FractureStatus.Size, "array '" + name + "' lies outside the binary file or is not 16-byte aligned");
            }

            public void CheckArrays(long binarySize)
            {
                // The crack arrays (drawing only) come together: a table that lists one needs both.
                if (Cracks && (Arrays[10] == null) != (Arrays[11] == null))
                    throw Fail(FractureStatus.Header, "the crack arrays come together: " +
                                                      (Arrays[10] == null ? "crack_ptr" : "crack_segments") + " missing");
                for (int i = 0; i < Arrays.Length; i++)
                {
                    if (!Needed(i))
                        continue;
                    ArrayEntry a = Arrays[i];
                    string name = ArrayNames[i];
                    if (a == null || a.DType == null || a.Shape == null)
                        throw Fail(FractureStatus.Header, "array '" + name + "' entry is missing or malformed");
                    if (a.DType != (ArrayIsInt[i] ? "int32" : "float32"))
                        throw Fail(FractureStatus.Header, "array '" + name + "' has the wrong dtype");
                    if (a.Shape.Length != ArrayRanks[i])
                        throw Fail(FractureStatus.Size, "array '" + name + "' has " + a.Shape.Length +
                                                        " dimensions, expected " + ArrayRanks[i]);
                    if (!a.ShapeOk)
                        throw Fail(FractureStatus.Size, "array '" + name + "' has a negative or non-integer size");
                    long count = 1;
                    foreach (long n in a.Shape) // saturate: a product beyond the file cannot match byte_length
                        count = n != 0 && count > (1L << 40) / n ? (1L << 40) + 1 : count * n;
                    if (a.Length < 0 || count * 4 != a.Length)
                        throw Fail(FractureStatus.Size, "array '" + name + "': shape and byte_length do not agree");
                    if (a.Offset < 0 || a.Offset % 16 != 0 || a.Offset > binarySize || a.Length > binarySize - a.Offset)
                        throw Fail(FractureStatus.Size, "array '" + name +
                                                        "' lies outside the binary file or is not 16-byte aligned");
                }
            }
        }

        // ------------------------------------------------------------------ JSON (RFC 8259, strict)

        // Objects become Dictionary<string, object>, arrays List<object>, strings string, numbers
        // JsonNumber, true/false bool, null null. Duplicate keys: the last one wins.
        internal sealed class JsonNumber
        {
            public string Text;
            public bool Integer;
        }

        internal sealed class Json
        {
            const int MaxDepth = 64;
            readonly string text;
            int at, depth;

            public Json(string text)
            {
                this.text = text;
            }

            public static bool AsInteger(object value, out long result)
            {
                var number = value as JsonNumber;
                result = 0;
                return number != null && number.Integer &&
                       long.TryParse(number.Text, NumberStyles.AllowLeadingSign, CultureInfo.InvariantCulture, out result);
            }

            public static bool AsNumber(object value, out double result)
            {
                var number = value as JsonNumber;
                result = 0;
                return number != null &&
                       double.TryParse(number.Text, NumberStyles.Float, CultureInfo.InvariantCulture, out result);
            }

            FractureRuntimeException Error()
            {
                return Fail(FractureStatus.Json, "header is not valid JSON (near character " + at + ")");
            }

            void Space()
            {
                while (at < text.Length && (text[at] == ' ' || text[at] == '\t' || text[at] == '\n' || text[at] == '\r'))
                    at++;
            }

            bool Eat(char c)
            {
                Space();
                if (at < text.Length && text[at] == c)
                {
                    at++;
                    return true;
                }
                return false;
            }

            public object ParseDocument()
            {
                object value = Value();
                Space();
                if (at != text.Length)
                    throw Error();
                return value;
            }

            object Value()
            {
                Space();
                if (at >= text.Length)
                    throw Error();
                char c = text[at];
                if (c == '{' || c == '[')
                {
                    if (++depth > MaxDepth)
                        throw Error();
                    object container = c == '{' ? (object)Object() : List();
                    depth--;
                    return container;
                }
                if (c == '"')
                    return String();
                if (c == '-' || (c >= '0' && c <= '9'))
                    return Number();
                foreach (string word in new[] { "true", "false", "null" })
                    if (string.CompareOrdinal(text, at, word, 0, word.Length) == 0)
                    {
                        at += word.Length;
                        return word == "null" ? null : (object)(word == "true");
                    }
                throw Error();
            }

            Dictionary<string, object> Object()
            {
                var result = new Dictionary<string, object>(StringComparer.Ordinal);
                at++;
                if (Eat('}'))
                    return result;
                do
                {
                    Space();
                    if (at >= text.Length || text[at] != '"')
                        throw Error();
                    string key = String();
                    if (!Eat(':'))
                        throw Error();
                    result[key] = Value();
                } while (Eat(','));
                if (!Eat('}'))
                    throw Error();
                return result;
            }

            List<object> List()
            {
                var result = new List<object>();
                at++;
                if (Eat(']'))
                    return result;
                do
                    result.Add(Value());
                while (Eat(','));
                if (!Eat(']'))
                    throw Error();
                return result;
            }

            string String()
            {
                var builder = new StringBuilder();
                at++;
                while (true)
                {
                    if (at >= text.Length)
                        throw Error();
                    char c = text[at++];
                    if (c == '"')
                        return builder.ToString();
                    if (c < 0x20)
                        throw Error();
                    if (char.IsSurrogate(c)) // from the UTF-8 decoder: always a valid pair
                    {
                        builder.Append(c);
                        continue;
                    }
                    if (c != '\\')
                    {
                        builder.Append(c);
                        continue;
                    }
                    if (at >= text.Length)
                        throw Error();
                    char escape = text[at++];
                    int index = "\"\\/bfnrt".IndexOf(escape);
                    if (index >= 0)
                    {
                        builder.Append("\"\\/\b\f\n\r\t"[index]);
                        continue;
                    }
                    if (escape != 'u')
                        throw Error();
                    int unit = Hex4();
                    if (unit >= 0xDC00 && unit <= 0xDFFF)
                        throw Error(); // a lone low surrogate
                    builder.Append((char)unit);
                    if (unit >= 0xD800 && unit <= 0xDBFF)
                    {
                        if (at + 1 >= text.Length || text[at] != '\\' || text[at + 1] != 'u')
                            throw Error();
                        at += 2;
                        int low = Hex4();
                        if (low < 0xDC00 || low > 0xDFFF)
                            throw Error();
                        builder.Append((char)low);
                    }
                }
            }

            int Hex4()
            {
                if (at + 4 > text.Length)
                    throw Error();
                int value = 0;
                for (int i = 0; i < 4; i++)
                {
                    int digit = "0123456789abcdef".IndexOf(char.ToLowerInvariant(text[at++]));
                    if (digit < 0)
                        throw Error();
                    value = value * 16 + digit;
                }
                return value;
            }

            JsonNumber Number()
            {
                int begin = at;
                bool integer = true;
                if (text[at] == '-')
                    at++;
                if (at < text.Length && text[at] == '0')
                    at++;
                else if (!Digits())
                    throw Error();
                if (at < text.Length && text[at] == '.')
                {
                    integer = false;
                    at++;
                    if (!Digits())
                        throw Error();
                }
                if (at < text.Length && (text[at] == 'e' || text[at] == 'E'))
                {
                    integer = false;
                    at++;
                    if (at < text.Length && (text[at] == '+' || text[at] == '-'))
                        at++;
                    if (!Digits())
                        throw Error();
                }
                return new JsonNumber { Text = text.Substring(begin, at - begin), Integer = integer };
            }

            bool Digits()
            {
                int begin = at;
                while (at < text.Length && text[at] >= '0' && text[at] <= '9')
                    at++;
                return at > begin;
            }
        }
    }
}
